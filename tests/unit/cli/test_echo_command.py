"""``ucal echo FILE.csv [--reference REF.csv] [--json]`` through CSV files (SPEC.md)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ucal.echo import build_reference
from ucal.sim.ascan import Digitiser, TransducerPulse, echo_shape, gate_around, synthesise

RunMain = Callable[[list[str]], tuple[int, str, str]]
ARRIVALS_NS = [67_000.3, 67_001.7, 67_004.9]


def write_csv(path: Path, t_ns: np.ndarray, columns: dict[str, np.ndarray]) -> Path:
    table = np.column_stack([t_ns, *columns.values()])
    np.savetxt(
        path, table, delimiter=",", header=",".join(["t_ns", *columns]), comments="", fmt="%.6f"
    )
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Three 10 MHz A-scans at 200 MS/s and 30 dB (the third clipped), and the reference
    averaged from 64 captures at 40 dB, as CSV files."""
    d = tmp_path_factory.mktemp("echo")
    rng = np.random.default_rng(11)
    shape = echo_shape(TransducerPulse(10.0), Digitiser(200.0, 12, 1.0))
    t0, n = gate_around(shape, 67_000.0)
    captures = synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=67_000.0 + 0.5 * rng.standard_normal(64),
        amplitude=0.5,
        noise_rms=0.005,
    )
    ref = build_reference(captures)
    ref_path = write_csv(
        d / "ref.csv", ref.t0_ns + ref.dt_ns * np.arange(ref.n), {"reference": ref.samples}
    )
    scans = synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=ARRIVALS_NS[:2],
        amplitude=0.5,
        noise_rms=0.0158,
    )
    scans += synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=ARRIVALS_NS[2:],
        amplitude=2.0,
        noise_rms=0.0158,
    )
    scan_path = write_csv(
        d / "scans.csv",
        scans[0].t_ns,
        {name: s.samples for name, s in zip("abc", scans, strict=True)},
    )
    return scan_path, ref_path


def test_json_times_every_a_scan_against_the_reference(
    files: tuple[Path, Path], run_main: RunMain
) -> None:
    scans, ref = files
    code, out, err = run_main(["echo", str(scans), "--reference", str(ref), "--json"])
    assert code == 0, err
    echoes = json.loads(out)["echoes"]
    assert [set(e) for e in echoes] == [
        {
            "tof_ns",
            "tof_std_ns",
            "amplitude",
            "snr_db",
            "centre_frequency_mhz",
            "bandwidth_mhz",
            "method",
            "clipped",
            "overlapped",
            "separated",
        }
    ] * 3
    for e, truth in zip(echoes, ARRIVALS_NS, strict=True):
        assert e["method"] == "reference"
        assert abs(e["tof_ns"] - truth) < 4 * e["tof_std_ns"] + 0.02
        assert 0.01 < e["tof_std_ns"] < 0.5
        assert e["centre_frequency_mhz"] == pytest.approx(10.0, rel=0.05)
    assert [e["clipped"] for e in echoes] == [False, False, True]  # rails found without bits
    assert echoes[0]["snr_db"] == pytest.approx(30.0, abs=1.0)
    assert echoes[2]["amplitude"] == pytest.approx(2.0, rel=0.03)


def test_without_reference_the_table_says_coarse(
    files: tuple[Path, Path], run_main: RunMain
) -> None:
    scans, _ = files
    code, out, err = run_main(["echo", str(scans)])
    assert code == 0, err
    assert "coarse: no reference echo" in out
    assert all(name in out for name in ("TOF (ns)", "σ (ns)", "SNR (dB)", " a ", " b ", " c "))
    code, out, _ = run_main(["echo", str(scans), "--json"])
    assert {e["method"] for e in json.loads(out)["echoes"]} == {
        "envelope (coarse: no reference echo)"
    }


@pytest.mark.parametrize(
    "content, words",
    [
        (None, "cannot read"),
        ("", "empty"),
        ("t_ns\n0\n1\n2\n3\n4\n5\n6\n7\n", "no A-scan columns after t_ns"),
        ("time,a\n" + "".join(f"{i},0\n" for i in range(10)), "the first column must be t_ns"),
        ("t_ns,a\n" + "".join(f"{i * i},0\n" for i in range(10)), "not uniformly sampled"),
        ("t_ns,a\n" + "".join(f"{i},x\n" for i in range(10)), "row 2: not numbers"),
        ("t_ns,a\n0,1\n1,2\n", "2 sample(s)"),
        ("t_ns,a,b\n" + "".join(f"{i},0\n" for i in range(10)), "expected 3 finite numbers"),
        # times in seconds (2 ns a sample written as 2e-9): refused, not 887 GiB allocated
        ("t_ns,a\n" + "".join(f"{i * 2e-9},{i % 2}\n" for i in range(10)), "times in seconds"),
        ("t_ns,a\n" + "".join(f"{i * 5000},{i % 2}\n" for i in range(10)), "outside the 0.05"),
        # a sample of 1e300 overflowed the estimator (exit 1, OverflowError)
        ("t_ns,a\n" + "".join(f"{i},{1e300 * (i % 2)}\n" for i in range(10)), "row 3, column 'a'"),
    ],
)
def test_bad_input_is_one_line_naming_the_file_exit_2(
    tmp_path: Path, run_main: RunMain, content: str | None, words: str
) -> None:
    path = tmp_path / "scans.csv"
    if content is not None:
        path.write_text(content, encoding="utf-8")
    code, out, err = run_main(["echo", str(path), "--json"])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"error: {path}: ") and words in lines[0]
    assert json.loads(out)["exit_code"] == 2


def test_a_bad_reference_names_the_reference(
    files: tuple[Path, Path], tmp_path: Path, run_main: RunMain
) -> None:
    scans, _ = files
    for text, words in (
        ("t_ns,a,b\n" + "".join(f"{i},0,0\n" for i in range(10)), "holds one echo"),
        ("t_ns,a\n" + "".join(f"{i + 5},{i % 2}\n" for i in range(10)), "t_ns = 0, is outside"),
        ("t_ns,a\n" + "".join(f"{(i - 5) * 1e-9},{i % 2}\n" for i in range(10)), "in seconds"),
    ):
        ref = tmp_path / "ref.csv"
        ref.write_text(text, encoding="utf-8")
        code, _, err = run_main(["echo", str(scans), "--reference", str(ref)])
        assert code == 2 and err.startswith(f"error: {ref}: ") and words in err, err
