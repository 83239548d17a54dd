"""`softcbf report --figure-format`: the rebuilt figures replace their copies in the other formats (issue 27)."""

from __future__ import annotations

from softcbf.cli import main
from softcbf_mj.outputs.report import FIGURE_SIZES_IN, PLOTS_DIR


def test_rebuilding_as_svg_leaves_no_stale_png_and_keeps_other_files(run_dir):
    plots = run_dir / PLOTS_DIR
    assert main(["report", str(run_dir), "--no-recording"]) == 0
    assert {p.name for p in plots.glob("*.png")} >= {f"{name}.png" for name in FIGURE_SIZES_IN}
    (plots / "my_notes.png").write_bytes(b"not a report figure")
    assert main(["report", str(run_dir), "--no-recording", "--figure-format", "svg"]) == 0
    names = {p.name for p in plots.iterdir()}
    assert names == {f"{name}.svg" for name in FIGURE_SIZES_IN} | {"my_notes.png"}
    assert all(f"plots/{name}.svg" in (run_dir / "report.md").read_text() for name in FIGURE_SIZES_IN)
    assert main(["report", str(run_dir), "--no-recording", "--figure-format", "pdf"]) == 0
    assert {p.name for p in plots.iterdir()} == {f"{name}.pdf" for name in FIGURE_SIZES_IN} | {"my_notes.png"}
