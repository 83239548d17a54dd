"""A scenario's printed table fits TERMINAL_COLUMNS characters a line, the full table is in the run folder
(softcbf_mj.outputs.metrics.write_table), and the peak force's column is "F peak [N]" (F_max is the limit)."""

from __future__ import annotations

import pytest

from controllers.governors.energy_governor import RECOMMENDED
from controllers.registry import label
from scenarios.camera_loop import TABLE as CAMERA_TABLE
from scenarios.mujoco_contact import TABLE as CONTACT_TABLE
from scenarios.paper_sim import TABLE as PAPER_TABLE
from softcbf_mj.outputs.metrics import TABLE_FILE, TERMINAL_COLUMNS, write_table
from softcbf_mj.outputs.report import SUMMARY_COLUMNS

LONGEST = label("c-erg", {k: str(v).lower() if isinstance(v, bool) else v for k, v in RECOMMENDED.items()})


def rows(columns, labels):
    """One row per label with every column's key set to a number of the widest kind the runs write."""
    return [{**{c[1]: -12345.678 if c[2] != "d" else 123456 for c in columns}, columns[0][1]: name} for name in labels]


@pytest.mark.parametrize("table", [CONTACT_TABLE, CAMERA_TABLE, PAPER_TABLE], ids=["mujoco_contact", "camera_loop",
                                                                                    "paper_sim"])
def test_the_printed_table_fits_and_the_file_holds_every_column(tmp_path, table):
    runs = rows(table, ["None", LONGEST, LONGEST + "x"])
    text = write_table(tmp_path, runs, table)
    assert max(len(line) for line in text.splitlines()) <= TERMINAL_COLUMNS, text
    full = (tmp_path / TABLE_FILE).read_text(encoding="utf-8")
    header = full.splitlines()[0]
    assert all(c[0] in header for c in table) and LONGEST in full and LONGEST + "x" in full
    shown = text.splitlines()
    width = len(shown[1].split("  ")[0])  # the label column's, from the dashes under the header
    assert len({line[:width].strip() for line in shown[2:5]}) == 3  # the shortened labels stay distinct
    left_out = len(table) - len(shown[1].split())  # the dashes: one run per printed column
    assert shown[-1].endswith(str(tmp_path / TABLE_FILE)) and (left_out == 0 or shown[-1].startswith(f"{left_out} more"))


def test_a_narrow_table_prints_whole_and_says_nothing_more(tmp_path):
    runs = rows(PAPER_TABLE[:3], ["None", "Low"])
    text = write_table(tmp_path, runs, PAPER_TABLE[:3])
    assert len(text.splitlines()) == 4 and (tmp_path / TABLE_FILE).is_file()


@pytest.mark.parametrize("table", [CONTACT_TABLE, CAMERA_TABLE, PAPER_TABLE, SUMMARY_COLUMNS])
def test_the_peak_force_is_headed_f_peak_not_f_max(table):
    headers = {c[1]: c[0] for c in table}
    assert headers["force_max_N"] == "F peak [N]"
    assert not any(h.startswith("F_max") for h in headers.values())
