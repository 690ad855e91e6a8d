"""The report's figure writer: the same files drawn here or by worker processes, and written whole."""

import numpy as np
import pytest

from piezopreload.reports import figures as F


def _figures(tmp_path, folder):
    t = np.linspace(0.0, 1.0, 200)
    return [(F.natural_frequency(t, 100 + t, 120 + t, 90.0), tmp_path / folder / f"f{i}.pdf") for i in range(3)]


def test_save_all_in_workers_writes_what_saving_here_writes(tmp_path):
    here = F.save_all(_figures(tmp_path, "here"), workers=1)
    seen = []
    pooled = F.save_all(_figures(tmp_path, "pool"), workers=2, progress=lambda i, n: seen.append((i, n)))
    assert [p.name for p in pooled] == [p.name for p in here]
    for a, b in zip(here, pooled, strict=True):
        assert a.read_bytes() == b.read_bytes(), f"{b} differs from {a}"
        assert a.read_bytes().startswith(b"%PDF")
    assert seen == [(1, 3), (2, 3), (3, 3)]


def test_a_failed_draw_leaves_no_partial_file(tmp_path, monkeypatch):
    fig, path = _figures(tmp_path, "x")[0]
    path.parent.mkdir(parents=True)
    path.write_bytes(b"the previous report's figure")

    def broken(*_a, **_k):
        raise RuntimeError("the disk is full")

    monkeypatch.setattr(fig, "savefig", broken)
    with pytest.raises(RuntimeError):
        F.save(fig, path)
    assert path.read_bytes() == b"the previous report's figure"
    assert [p.name for p in path.parent.iterdir()] == [path.name], "a temporary file was left behind"


def test_every_plot_method_is_typed_to_return_a_figure_and_nothing_uses_pyplot():
    """Every result's ``plot()`` returns a matplotlib Figure made without pyplot (no global figure state): its
    annotation says so (a type checker then holds each body to it), and no module of the package imports pyplot."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    folders = ("core", "models", "artifacts", "design", "tuning", "rig", "reports", "piezopreload")
    plots, pyplot = [], []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):
                if isinstance(node, ast.FunctionDef) and node.name == "plot":
                    plots.append((f"{path.relative_to(root)}:{node.lineno}", ast.unparse(node.returns)))
                if isinstance(node, ast.ImportFrom | ast.Import):
                    names = [getattr(node, "module", None) or ""] + [a.name for a in node.names]
                    if any(n == "matplotlib.pyplot" or n.endswith(".pyplot") or n == "pyplot" for n in names):
                        pyplot.append(f"{path.relative_to(root)}:{node.lineno}")
    assert len(plots) >= 19
    assert [p for p in plots if p[1] != "Figure"] == []
    assert pyplot == []
