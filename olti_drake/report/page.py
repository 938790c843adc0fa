"""Building blocks of the calibration report pages: HTML helpers, the page accumulator, the ISO 230-2
section and the figures every kind of result shares (reversal values, residuals).

Used by :mod:`olti_drake.report.html` (SCARA and machine-tool pages) and
:mod:`olti_drake.report.serial_report` (N-joint robots). Units: the page shows lengths in mm with
uncertainties in µm, angles in mdeg.

**Every number carries the hash of its data file** (issue 26, item 4): a :class:`Page` made with the result file
(``Page(out_dir, result_path)``) stamps every text element it is given (table cells, paragraphs, headings,
figure captions and images: :data:`STAMPED`) with ``data-sha256="<sha256 of the file>"``, and the page's top
lists every file with its sha256 (:meth:`Page.legend`). The file is the result's by default; a section whose
numbers come from another file says so once, after its ``<h2>``, by ``page.source(path)`` (``columns={index:
path}``: table columns from yet another file, e.g. the u of an uncertainty file); the next ``<h2>`` returns to
the result. A new report (e.g. a five-axis page) gets the stamps by building its :class:`Page` with the result
path and calling :meth:`Page.source` where a section's data is another file's; nothing else.
"""

import base64
import html
import itertools
import os
import re
from typing import List

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.five_axis_io import file_sha256
from olti_drake.io.outputs import make_dir
from olti_drake.report.iso230 import ARCSEC_PER_DEG, EXTREME, NOT_AVAILABLE, STATISTICS

ISO_LABELS = {
    "B": ("B", "reversal value of the axis (B_i of largest |B_i|, sign kept)"),
    "B_mean": ("B̄", "mean reversal value of the axis"),
    "E_forward": ("E↑", "unidirectional systematic positional deviation, + direction"),
    "E_reverse": ("E↓", "unidirectional systematic positional deviation, − direction"),
    "E": ("E", "bidirectional systematic positional deviation of the axis"),
    "M": ("M", "range of the mean bidirectional positional deviation of the axis"),
}

CSS = """
body{font-family:sans-serif;max-width:1300px;margin:1.5em auto;padding:0 1em;color:#222;line-height:1.4}
h1{font-size:1.5em;border-bottom:2px solid #446;padding-bottom:.2em}
h2{font-size:1.2em;margin-top:1.8em;border-bottom:1px solid #99a}
h3{font-size:1.05em}
table{border-collapse:collapse;margin:.6em 0;font-size:.88em}
th,td{border:1px solid #bbc;padding:.2em .55em;text-align:right}
th{background:#eef}
td.l,th.l{text-align:left}
dl{display:grid;grid-template-columns:max-content auto;gap:.15em 1em}
dt{font-weight:bold}
dd{margin:0}
figure{margin:1em 0}
figure img{max-width:100%;border:1px solid #ccd}
figcaption{font-size:.88em;color:#445}
.note{background:#f6f6ee;border-left:4px solid #cc9;padding:.4em .8em;font-size:.9em}
"""


# -- small helpers -------------------------------------------------------------------------------------
_LEFT = ' class="l"'

def e(text) -> str:
    return html.escape(str(text), quote=True)


def table(header, rows, left=(0,)) -> str:
    """An HTML table; every cell escaped. ``left``: column indices aligned left."""
    def cells(tag, values):
        return "".join(f"<{tag}{_LEFT if i in left else ''}>{e(v)}</{tag}>" for i, v in enumerate(values))

    body = "".join(f"<tr>{cells('td', r)}</tr>" for r in rows)
    return f"<table><tr>{cells('th', header)}</tr>{body}</table>"


def p(text, cls=None) -> str:
    attr = f' class="{cls}"' if cls else ""
    return f"<p{attr}>{e(text)}</p>"


def num(v, fmt) -> str:
    return "—" if v is None or not np.isfinite(v) else format(v, fmt)


def check_uncertainty(unc: dict, raw: dict, keys, unc_path, result_path) -> None:
    """The uncertainty object must have every value key of the result with the same shape."""
    def walk(u, r, prefix):
        for k in keys if prefix == "" else r:
            name = f"{prefix}{k}"
            if k not in r or isinstance(r[k], str):  # (a label, e.g. tracker_frame.convention: no value)
                continue
            if k not in u:
                raise InputError(f"{os.fspath(unc_path)}: does not match {os.fspath(result_path)}: missing key "
                                 f"'{name}'")
            if isinstance(r[k], dict):
                if not isinstance(u[k], dict):
                    raise InputError(f"{os.fspath(unc_path)}: does not match {os.fspath(result_path)}: '{name}' "
                                     f"is not an object")
                walk(u[k], {kk: vv for kk, vv in r[k].items() if kk != "grid_deg"}, name + ".")
                continue
            try:
                su, sr = np.shape(np.asarray(u[k], dtype=float)), np.shape(np.asarray(r[k], dtype=float))
            except (TypeError, ValueError):
                raise InputError(f"{os.fspath(unc_path)}: '{name}' is not numeric") from None
            if su != sr:
                raise InputError(f"{os.fspath(unc_path)}: does not match {os.fspath(result_path)}: '{name}' has "
                                 f"shape {su}, the result {sr}")
            if not np.all(np.isfinite(np.asarray(u[k], dtype=float))) or np.any(np.asarray(u[k], dtype=float) < 0):
                raise InputError(f"{os.fspath(unc_path)}: '{name}' must hold finite standard uncertainties >= 0")

    walk(unc, raw, "")


def png_uri(path) -> str:
    with open(path, "rb") as f:
        return "data:image/png;base64," + base64.b64encode(f.read()).decode("ascii")


#: The elements that show text and so carry ``data-sha256`` (module docstring); an element stamped already keeps
#: its own.
STAMPED = ("td", "th", "p", "h1", "h2", "h3", "dt", "dd", "figcaption", "img", "li", "caption")
_STAMP = re.compile(r"<(" + "|".join(STAMPED) + r")(?=[\s>/])(?![^>]*data-sha256)")
_CELL = re.compile(r'<(td|th) data-sha256="([0-9a-f]*)"')
_ROW = re.compile(r"<tr>.*?</tr>", re.S)


def stamp(s: str, digest: str, columns=None) -> str:
    """``s`` with ``data-sha256="digest"`` on every :data:`STAMPED` element; ``columns`` {cell index: digest}:
    table cells of those columns carry their own."""
    s = _STAMP.sub(lambda m: f'<{m[1]} data-sha256="{digest}"', s)
    if not columns:
        return s

    def row(m):  # (cells counted per row: the i-th cell of a row is column i)
        k = itertools.count()
        return _CELL.sub(lambda c: f'<{c[1]} data-sha256="{columns.get(next(k), c[2])}"', m[0])

    return _ROW.sub(row, s)


class Page:
    """Accumulates HTML sections and figures (written as PNG into ``out_dir`` and embedded); with ``data`` (the
    result file) every element is stamped with its data file's sha256 (module docstring)."""

    def __init__(self, out_dir, data=None):
        self.out_dir = out_dir
        self.parts: List[str] = []
        self.written: List[str] = []
        self.header_rows: list = []  # (label, value) of the page header
        self.iso = None  # {axis: AxisStatistics} of a SCARA error map
        self.sources: dict = {}  # {file: sha256}, in order of use: the legend
        self.default = self.current = self.digest(data) if data is not None else None
        self.columns: dict = {}

    def digest(self, path) -> str:
        name = os.fspath(path)
        if name not in self.sources:
            self.sources[name] = file_sha256(name)
        return self.sources[name]

    def source(self, path, columns=None) -> None:
        """The numbers added from now to the next ``<h2>`` come from ``path`` (``None``: the result's);
        ``columns`` {table column index: path} those columns' from another file."""
        self.current = self.default if path is None else self.digest(path)
        self.columns = {i: self.digest(c) for i, c in (columns or {}).items() if c is not None}
        if self.parts and self.parts[-1].startswith("<h2") and self.current is not None:  # (the section's heading)
            self.parts[-1] = re.sub(r'data-sha256="[0-9a-f]*"', f'data-sha256="{self.current}"', self.parts[-1])

    def add(self, s: str):
        if s.startswith("<h2"):  # a new section: the result's numbers until it says otherwise
            self.current, self.columns = self.default, {}
        self.parts.append(s if self.current is None else stamp(s, self.current, self.columns))

    def legend(self) -> str:
        """The files the page's numbers come from, each with its sha256 (each row stamped with its own)."""
        if not self.sources:
            return ""
        rows = "".join(f'<tr><td class="l" data-sha256="{d}">{e(f)}</td><td class="l" data-sha256="{d}">{d}</td>'
                       f"</tr>" for f, d in self.sources.items())
        return (f'<p data-sha256="{self.default}">Data files of this page: every number carries the sha256 of the '
                f'file it came from (attribute data-sha256).</p><table><tr><th class="l" data-sha256="{self.default}">'
                f'file</th><th class="l" data-sha256="{self.default}">sha256</th></tr>{rows}</table>')

    def figure(self, make, name: str, caption: str):
        """``make(path)`` writes the PNG; the page embeds it as a data: URI with ``caption``."""
        path = os.path.join(self.out_dir, name)
        make_dir(self.out_dir)  # only now: bad input found earlier leaves nothing behind
        make(path)
        self.written.append(path)
        self.add(f'<figure><img alt="{e(caption)}" src="{png_uri(path)}">'
                 f"<figcaption>{e(caption)} (also written as {e(name)})</figcaption></figure>")


def fit_rows(raw) -> list:
    """Solver, iterations and condition number of a result, where present."""
    rows = []
    for key, label in (("solver", "solver"), ("iterations", "iterations"), ("condition_number", "condition number")):
        if key in raw:
            v = raw[key]
            rows.append((label, format(v, ".3g") if isinstance(v, float) else v))
    return rows


def plot_reversal(stats, truth_stats, k, path, method):
    """B_i (mdeg) per node with U (k) error bars, B̄ and the truth: the ISO 230-2 reversal values."""
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    fig, axes = axis_panels(plt, len(stats), 4.2)
    for ax, axis in zip(axes, stats):
        s = stats[axis]
        g = s.positions_deg
        yerr = None if s.u_reversal_deg is None else 1e3 * k * s.u_reversal_deg
        ax.errorbar(g, 1e3 * s.reversal_deg, yerr=yerr, fmt="o", color="tab:purple", capsize=3, ms=5,
                    label="B_i = x̄↑_i − x̄↓_i, identified" + (f", U (k = {k:g})" if yerr is not None else ""))
        ax.axhline(1e3 * s.B_mean_deg, color="tab:purple", lw=1, ls="--", label=f"B̄ = {1e3 * s.B_mean_deg:.2f} mdeg")
        ax.plot([g[s.B_index]], [1e3 * s.B_deg], "s", mfc="none", color="k", ms=11,
                label=f"B = {1e3 * s.B_deg:.2f} mdeg (largest |B_i|)")
        if truth_stats is not None:
            t = truth_stats[axis]
            ax.plot(t.positions_deg, 1e3 * t.reversal_deg, "x-", color="0.4", lw=1, label="truth B_i")
        ax.set(xlabel=command_label(axis), ylabel="reversal value, mdeg",
               title=f"{axis}: reversal values at the map nodes (ISO 230-2 B_i)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Reversal values from the identified error map" + (f" -- u: {method}" if method else ""),
                 fontsize=10)
    return _save(fig, plt, path)


def axis_panels(plt, n: int, height: float):
    """A figure with one panel per axis: two per row (a SCARA's J1, J2 side by side; six joints in three rows)."""
    cols = min(n, 2)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, height * rows), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, list(axes.ravel()[:n])


def command_label(axis: str) -> str:
    """``J1 command angle θ1*, deg`` for the SCARA's axis names, ``<joint> command angle θ*, deg`` otherwise."""
    if len(axis) >= 2 and axis[0] == "J" and axis[1:].isdigit():
        return f"{axis} command angle θ{axis[1:]}*, deg"
    return f"{axis} command angle θ*, deg"


def plot_residuals(index, residual_mm, group, label, path):
    """Residuals (µm) vs reading index, coloured per reflector (station), and their histogram."""
    from olti_drake.report.figures import _pyplot, _save

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.2), gridspec_kw={"width_ratios": [3, 1]})
    r = 1e3 * np.asarray(residual_mm)
    for j in np.unique(group):
        s = group == j
        rms = np.sqrt(np.mean(r[s] ** 2))
        axes[0].plot(index[s], r[s], ".", ms=3, label=f"{label} {j}: RMS {rms:.2f} µm")
        axes[1].hist(r[s], bins=30, histtype="step", lw=1.2, label=f"{label} {j}")
    axes[0].axhline(0, color="k", lw=0.5)
    axes[0].set(xlabel="reading index (valid readings, file order)", ylabel="residual, µm",
                title=f"Residuals of the identified model per {label}")
    axes[1].set(xlabel="residual, µm", ylabel="readings", title="Distribution")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    return _save(fig, plt, path)


def iso_section(page, stats, truth_stats, k, u_note, truth_note):
    page.add("<h2>ISO 230-2 style positioning statistics per axis</h2>")
    page.add(p("Target positions P_i are the map nodes θ*_i; the mean unidirectional positional deviations are "
                "the identified node values x̄↑_i = Δθ(θ*_i, +1), x̄↓_i = Δθ(θ*_i, −1) (Eq. (7) of 000). These "
                "are systematic statistics of the identified model, not of repeated runs (ISO 230-2:2014 terms "
                "and definitions). All except the node values are differences of node values and so do not "
                "depend on the gauge constant of a map level (e.g. the J1 level of a SCARA)."))
    page.add(p("Not available: " + " ".join(NOT_AVAILABLE.values()), "note"))
    page.add(p(u_note, "note"))
    for axis in stats:
        s = stats[axis]
        t = None if truth_stats is None else truth_stats[axis]
        page.add(f"<h3>{e(axis)} ({s.n_nodes} target positions, {s.positions_deg[0]:g} … "
                 f"{s.positions_deg[-1]:g} deg)</h3>")
        header = ["symbol", "ISO 230-2 term", "mdeg", "arcsec", "u (k = 1), mdeg", f"U (k = {k:g}), mdeg",
                  "attained at"]
        if t is not None:
            header += ["truth, mdeg", "(est − truth)/u"]
        rows = []
        for name in STATISTICS:
            sym, term = ISO_LABELS[name]
            v = s.value(name)
            u = s.u.get(name)
            where = s.where.get(name)
            if name == "B":
                at = f"θ* = {s.positions_deg[where]:g}°"
            elif name == "E":
                (i, di), (j, dj) = where
                at = f"max {s.positions_deg[i]:g}° ({'+' if di > 0 else '−'}), min {s.positions_deg[j]:g}° " \
                     f"({'+' if dj > 0 else '−'})"
            elif name in EXTREME:
                at = f"max {s.positions_deg[where[0]]:g}°, min {s.positions_deg[where[1]]:g}°"
            else:
                at = "all nodes"
            if name in EXTREME and s.ambiguous.get(name):
                at += " (runner-up within 2u: u optimistic)"
            row = [sym, term, f"{1e3 * v:.3f}", f"{ARCSEC_PER_DEG * v:.2f}", num(None if u is None else 1e3 * u, ".3f"),
                   num(None if u is None else 1e3 * k * u, ".3f"), at]
            if t is not None:
                tv = t.value(name)
                row += [f"{1e3 * tv:.3f}", num(None if not u else (v - tv) / u, "+.2f")]
            rows.append(row)
        page.add(table(header, rows, left=(0, 1, 6)))
        nh = ["θ*_i, deg", "x̄↑_i, mdeg", "u", "x̄↓_i, mdeg", "u", "B_i, mdeg", "u", "x̄_i, mdeg", "u"]
        if t is not None:
            nh += ["truth B_i, mdeg"]
        nrows = []
        for i in range(s.n_nodes):
            def uu(a):
                return num(None if a is None else 1e3 * a[i], ".3f")
            row = [f"{s.positions_deg[i]:g}", f"{1e3 * s.forward_deg[i]:.3f}", uu(s.u_forward_deg),
                   f"{1e3 * s.reverse_deg[i]:.3f}", uu(s.u_reverse_deg), f"{1e3 * s.reversal_deg[i]:.3f}",
                   uu(s.u_reversal_deg), f"{1e3 * s.mean_deg[i]:.3f}", uu(s.u_mean_deg)]
            if t is not None:
                row.append(f"{1e3 * t.reversal_deg[i]:.3f}" if t.n_nodes == s.n_nodes
                           and np.allclose(t.positions_deg, s.positions_deg) else "—")
            nrows.append(row)
        page.add(table(nh, nrows, left=()))
    if truth_note:
        page.add(p(truth_note, "note"))


