"""``calib-oed design --prior-from``: kpi_model's joint-space prior from an identification JSON,
and the contract on a bad file (exit 2, one line naming the option, no file written)."""

from __future__ import annotations

import json

import pytest

from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main

FAST = ["-n", "30", "--no-refine", "--no-certificate", "--pool", "300", "--quiet"]


@pytest.fixture(scope="module")
def identification(tmp_path_factory):
    path = tmp_path_factory.mktemp("prior") / "identification.json"
    fitted = {"sigma_mm": 0.04, "length_scales_deg": [50, 50, 50, 90, 90, None], "kernel": "matern52",
              "harmonic_mm": [[0.02, 0.01]] * 6}
    path.write_text(json.dumps({"model_error": {"fitted": fitted}, "p": {"joint2.gain": 2e-4}}))
    return path


def test_the_design_record_carries_the_identifications_prior(identification, tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["design", "fms_kr16", *FAST, "--prior-from", str(identification), "-o", str(out),
                 "--json"]) == EXIT_OK
    record = json.loads(capsys.readouterr().out)
    prior = record["solver"]["model_error"]
    assert record["criterion"] == "kpi_model" and prior["source"].startswith(str(identification))
    assert prior["gain_urad_per_rad"][1] == pytest.approx(200.0) and prior["once_arcsec"][5] == 0.0


@pytest.mark.parametrize("text, says", [
    ("not json", "cannot read"),
    (json.dumps({"p": {}}), "no model_error.fitted"),
])
def test_a_bad_file_exits_2_naming_the_option(tmp_path, capsys, text, says):
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    out = tmp_path / "d"
    assert main(["design", "fms_kr16", *FAST, "--prior-from", str(bad), "-o", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--prior-from" in err and says in err and "Traceback" not in err
    assert not out.exists()
