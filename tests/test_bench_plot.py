"""softcbf.bench.plots.write_plot: the legend sits outside the data, and every panel's quantity axis carries its unit."""

from __future__ import annotations

from matplotlib.figure import Figure

from softcbf.bench.plots import PLOTTED, write_plot


def bench_of(filters: list[str]) -> dict:
    cases = ["paper_sim_limits", "step", "mujoco_contact", "camera_loop"]
    results = [{"filter": f, "case": c, "rho_min_meas": 0.9 - 0.3 * i, "force_max_N": 0.1 + 0.05 * i,
                "u_dev_rms_hPa": 10.0 * (i + 1), "filter_us_p99": 100.0 * (j + 1), "f_max_N": 0.16}
               for j, f in enumerate(filters) for i, c in enumerate(cases)]
    return {"battery": cases, "filters": filters, "results": results}


def test_legend_outside_every_panel_and_units_on_every_axis(tmp_path, monkeypatch):
    measured: list[tuple] = []
    original = Figure.savefig

    def keep(self, *args, **kwargs):  # measure as drawn for the file, before write_plot closes the figure
        result = original(self, *args, **kwargs)
        renderer = self.canvas.get_renderer()
        legends = list(self.legends) + [ax.get_legend() for ax in self.axes if ax.get_legend() is not None]
        measured.append(([legend.get_window_extent(renderer) for legend in legends],
                         [ax.get_window_extent(renderer) for ax in self.axes], self.bbox, [ax.get_xlabel() for ax in self.axes]))
        return result

    monkeypatch.setattr(Figure, "savefig", keep)
    write_plot(tmp_path / "bench.png", bench_of(["e-erg", "paper-cbf HW-High", "qsg", "none"]))
    assert (tmp_path / "bench.png").stat().st_size > 0
    ((legends, panels, page, labels),) = measured
    assert len(legends) == 1
    box = legends[0]
    for panel in panels:
        assert not box.overlaps(panel), "the legend covers a panel's data"
    assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1  # not cut off
    assert labels == [title for _, title in PLOTTED]
    assert all(label.endswith("]") and "[" in label for label in labels)
    assert labels[0] == "ρ_meas min [1]"
