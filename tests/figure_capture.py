"""Look at what a figure shows, not at its PNG size: the matplotlib Figures as they are saved.

``captured_figures()`` wraps ``Figure.savefig`` for the duration of a ``with`` block and records
every figure under its file name (the basename), then saves as usual; closing a figure through
pyplot afterwards leaves its axes and artists intact for the test to inspect. The helpers below
read back what a reader of the figure sees: titles, axis labels, legend entries, annotations and
the data of the plotted lines.
"""

from __future__ import annotations

import os
import re
from contextlib import contextmanager
from unittest import mock

import numpy as np


@contextmanager
def captured_figures():
    """{file basename: matplotlib Figure} of every figure saved inside the block."""
    from matplotlib.figure import Figure

    saved = {}
    original = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        name = os.path.basename(os.fspath(fname))
        # olti_drake.io.outputs writes atomically: the figure is saved to ".NAME.XXXX.tmp", then renamed to NAME.
        atomic = re.fullmatch(r"\.(.+)\.[^.]+\.tmp", name)
        saved[atomic.group(1) if atomic else name] = self
        return original(self, fname, *args, **kwargs)

    with mock.patch.object(Figure, "savefig", savefig):
        yield saved


def suptitle(fig) -> str:
    return fig._suptitle.get_text() if fig._suptitle is not None else ""


def legend_labels(ax) -> list:
    """The legend entries as drawn (empty when the axes has no legend)."""
    legend = ax.get_legend()
    return [t.get_text() for t in legend.get_texts()] if legend is not None else []


def annotations(ax) -> dict:
    """{text: (x, y) data position} of the annotations of an axes."""
    from matplotlib.text import Annotation

    return {t.get_text(): tuple(t.xy) for t in ax.texts if isinstance(t, Annotation)}


def line(ax, label) -> np.ndarray:
    """(N, 2) x, y data of the one line whose legend label is ``label``."""
    found = [ln for ln in ax.get_lines() if ln.get_label() == label]
    labels = [ln.get_label() for ln in ax.get_lines()]
    assert len(found) == 1, f"{len(found)} lines labelled {label!r}; labels: {labels}"
    return np.column_stack([found[0].get_xdata(), found[0].get_ydata()]).astype(float)


def errorbar(ax, label):
    """(x, y, half length of the vertical error bar) of the one errorbar series labelled ``label``."""
    found = [c for c in ax.containers if c.get_label() == label]
    assert len(found) == 1, f"{len(found)} error bar series labelled {label!r}"
    data, _, (bars,) = found[0].lines
    seg = np.array([s[:, 1] for s in bars.get_segments()])
    return (np.asarray(data.get_xdata(), dtype=float), np.asarray(data.get_ydata(), dtype=float),
            (seg[:, 1] - seg[:, 0]) / 2)


def lines_with(ax, marker=None, linestyle=None, color=None) -> list:
    """The lines of an axes with the given marker / linestyle / colour (None: any)."""
    from matplotlib.colors import to_rgba

    out = []
    for ln in ax.get_lines():
        if marker is not None and ln.get_marker() != marker:
            continue
        if linestyle is not None and ln.get_linestyle() != linestyle:
            continue
        if color is not None and to_rgba(ln.get_color()) != to_rgba(color):
            continue
        out.append(ln)
    return out


def points(lines) -> np.ndarray:
    """(N, 2) x, y of all the given lines' data, concatenated."""
    if not lines:
        return np.empty((0, 2))
    return np.concatenate([np.column_stack([ln.get_xdata(), ln.get_ydata()]).astype(float) for ln in lines])


def same_points(a, b, atol=1e-9) -> bool:
    """True if two (N, 2) point sets are equal up to order (sorted lexicographically)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        return False
    ka, kb = np.lexsort(a.T[::-1]), np.lexsort(b.T[::-1])
    return bool(np.allclose(a[ka], b[kb], rtol=0, atol=atol))
