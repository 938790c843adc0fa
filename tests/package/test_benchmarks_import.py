"""Every benchmark script still imports: the test layout moved once under a benchmark that reached into
``tests.test_five_axis_identify`` and nothing noticed (benchmarks are run by hand, not by the suite)."""

import importlib.util
import pathlib

import pytest

BENCHMARKS = sorted((pathlib.Path(__file__).resolve().parents[2] / "benchmarks").glob("*.py"))


@pytest.mark.parametrize("path", BENCHMARKS, ids=[p.stem for p in BENCHMARKS])
def test_benchmark_imports(path):
    spec = importlib.util.spec_from_file_location(f"_bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # runs the imports; main() stays behind its __main__ guard
    assert callable(getattr(module, "main", None)) or path.stem == "timing", f"{path.name} has no main()"
