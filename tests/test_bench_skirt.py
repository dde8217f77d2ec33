"""``rtsid bench skirt --defaults-only``: rtsid tv's defaults against the old ones."""

from __future__ import annotations

import pytest

from rtsid.cli import main


@pytest.mark.slow  # simulates the study's 200 s records and searches every family's N_p
def test_defaults_table_meets_the_floor_on_the_sinusoidal_case(capsys):
    assert main(["bench", "skirt", "--quick", "--defaults-only"]) == 0
    out = capsys.readouterr().out
    rows = [line.split(" | ") for line in out.splitlines() if line.startswith("| SIN2 | ")]
    assert [row[1] for row in rows] == ["old", "new"]
    old_vaf, new_vaf = (float(row[3]) for row in rows)
    assert new_vaf >= 99.0 > 90.0 > old_vaf
    assert "| CS3 | new | " in out
    assert "validation VAF ≥ 99 % and f_n RMSE ≤ 0.03 Hz): met (" in out
