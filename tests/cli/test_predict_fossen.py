"""`auvid predict` on a table and on a log (same predictions), its usage errors; the Fossen YAML and UUV
Simulator export, loaded back and simulated against the project's own free run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import auvid
from pipeline import cli
from pipeline.fossen import FossenError, load_fossen, load_uuv, write_fossen, write_uuv
from pipeline.rollout import segment_runs
from tests.cli.model_helpers import build_run

NU, TAU, G = ["u_mps", "v_mps", "r_radps"], ["tau_u_N", "tau_v_N", "tau_r_Nm"], ["g_u_N", "g_v_N", "g_r_Nm"]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_run(tmp_path_factory.mktemp("predict_run"))


def _predict(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    code = cli.main(["predict", *args, "-q"])
    out = capsys.readouterr()
    return code, out.out + out.err


def test_predict_on_a_table_and_on_its_log_agree(run: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    table = run / "data/derived/test.parquet"
    code, text = _predict(capsys, str(table), "--root", str(run), "-o", str(tmp_path / "t.parquet"))
    assert code == 0, text
    got = pq.read_table(tmp_path / "t.parquet").to_pandas()
    rows = pq.read_table(table).to_pandas()
    models = auvid.load(run)
    ok = rows[NU + TAU + G].notna().all(axis=1).to_numpy()
    want = models["ls"].predict(rows[NU].to_numpy()[ok], (rows[TAU].to_numpy() - rows[G].to_numpy())[ok])
    np.testing.assert_allclose(got.loc[ok, [f"ls/{c}" for c in ("udot_mps2", "vdot_mps2", "rdot_radps2")]], want,
                               rtol=1e-12)
    assert {"gp/udot_mps2/lower", "gp/udot_mps2/upper", "coupled_rbf_svr/rdot_radps2", "udot_mps2", "t_ns"} \
        <= set(got.columns) and "ls/udot_mps2/lower" not in got.columns
    np.testing.assert_array_equal(got["t_ns"], rows["t_ns"])
    code, text = _predict(capsys, str(table), "--root", str(run), "--model", "ls", "-o", str(tmp_path / "t.csv"))
    assert code == 0, text
    csv = pd.read_csv(tmp_path / "t.csv")
    assert [c for c in csv.columns if "/" in c] == ["ls/udot_mps2", "ls/vdot_mps2", "ls/rdot_radps2"]
    np.testing.assert_allclose(csv["ls/udot_mps2"], got["ls/udot_mps2"], rtol=1e-12)
    # the log goes through ingest..derive with the run's configs: the same rows, the same predictions
    log_path = str(run / "data/raw/test.mcap")
    code, text = _predict(capsys, log_path, "--root", str(run), "-o", str(tmp_path / "l.parquet"))
    assert code == 0, text
    from_log = pq.read_table(tmp_path / "l.parquet").to_pandas()
    assert (from_log["trial"] == "test").all()
    pd.testing.assert_frame_equal(from_log.drop(columns="trial"), got, rtol=1e-9)


@pytest.mark.parametrize("case", ["missing_column", "no_input", "bad_suffix", "unknown_model", "no_run"])
def test_predict_usage_errors_exit_2_naming_file_and_column(case: str, run: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    table = tmp_path / "in.parquet"
    pq.write_table(pq.read_table(run / "data/derived/test.parquet").drop(["tau_v_N"]), table)
    out = tmp_path / "out.parquet"
    args = {"missing_column": [str(table), "--root", str(run), "-o", str(out)],
            "no_input": [str(tmp_path / "nope.mcap"), "--root", str(run), "-o", str(out)],
            "bad_suffix": [str(table), "--root", str(run), "-o", str(tmp_path / "out.xlsx")],
            "unknown_model": [str(table), "--root", str(run), "--model", "svr", "-o", str(out)],
            "no_run": [str(table), "--root", str(tmp_path), "-o", str(out)]}[case]
    code, text = _predict(capsys, *args)
    assert code == 2, text
    expected = {"missing_column": f"{table}: field 'tau_v_N': column 'tau_v_N'", "no_input": "nope.mcap",
                "bad_suffix": "'.xlsx'", "unknown_model": "--model svr", "no_run": "not a run directory"}[case]
    assert expected in text and "Traceback" not in text
    assert not out.exists() and not list(tmp_path.glob(".out*"))


def _first_run(run: Path) -> tuple[pd.DataFrame, np.ndarray, int, int]:
    free = pq.read_table(run / "data/simulation/test/free_run.parquet").to_pandas()
    rows = pq.read_table(run / "data/derived/test.parquet").to_pandas().set_index("t_ns").loc[free["t_ns"]]
    a, b = segment_runs(free["t_ns"].to_numpy(), rows["segment"].to_numpy(),
                        float(np.median(np.diff(free["t_ns"]))) * 1e-9)[0]
    return free, rows[TAU].to_numpy() - rows[G].to_numpy(), a, b


def test_fossen_and_uuv_exports_reproduce_the_project_s_free_run(run: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["export", str(run), "--fossen", "ls", "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    yaml_path, xml_path = tmp_path / "fossen_ls.yaml", tmp_path / "uuv_ls.xml"
    free, tau, a, b = _first_run(run)
    stage = free[[f"ls/{c}" for c in NU]].to_numpy()[a:b]
    t_s = np.arange(b - a) * float(np.median(np.diff(free["t_ns"]))) * 1e-9
    fossen = load_fossen(yaml_path)
    for model in (fossen, load_uuv(xml_path, fossen.M_RB, ["u", "v", "r"])):
        ours = model.simulate(free[NU].to_numpy()[a], tau[a:b], t_s)
        rms = np.sqrt(np.mean((ours - stage) ** 2, axis=0)) / np.sqrt(np.mean(stage**2, axis=0))
        assert (rms < 0.01).all(), rms
    # every identified coefficient: value inside its interval, the trials it came from; the same bytes again
    import yaml

    doc = yaml.safe_load(yaml_path.read_text())
    assert sorted(doc["coefficients"]) == sorted(f"D_{k}[{d},{d}]" for k in "lq" for d in "uvr")
    for c in doc["coefficients"].values():
        assert c["ci95"][0] < c["value"] < c["ci95"][1] and c["trials"] == ["a"] and len(c["model"]["sha256"]) == 64
    assert doc["not_identified"] == ["w", "p", "q"] and doc["D_l"][2][2] == 0.0
    assert "<linear_damping>" + repr(-doc["D_l"][0][0]) in xml_path.read_text()
    first = yaml_path.read_bytes()
    write_fossen(auvid.load(run)["ls"], yaml_path)
    assert yaml_path.read_bytes() == first


def test_only_a_linear_quadratic_model_has_a_fossen_form(run: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(FossenError, match="not a linear-quadratic"):
        write_uuv(auvid.load(run)["gp"], tmp_path / "gp.xml")
    assert cli.main(["export", str(run), "--fossen", "gp", "--out", str(tmp_path)]) == 2
    assert "not a linear-quadratic" in capsys.readouterr().err and not list(tmp_path.iterdir())
    bad = tmp_path / "bad.yaml"
    write_fossen(auvid.load(run)["ls"], bad)
    bad.write_text(bad.read_text().replace("D_q:", "D_q_typo:"))
    with pytest.raises(FossenError, match="'D_q' missing"):
        load_fossen(bad)
