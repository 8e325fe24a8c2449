"""A record without an echo is "no echo", never a time: in ``estimate_echo``, ``ucal echo``
(exit 3 naming the file and the column, ``--json`` valid JSON) and the host's timer; the
flags ``overlapped`` and ``clipped`` in ``--json``, and ``clipped`` right on clean records."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from ascan_generator import Pulse, record_axis, records

from drivers.digitizer.base import AScanRecord
from ucal.echo import AScan, NoEcho, build_reference, estimate_echo
from ucal.echo.host import HostEchoTimer

RunMain = Callable[[list[str]], tuple[int, str, str]]
ARRIVAL_NS = 20_000.0
PULSE = Pulse(10.0, 200.0)


def strict_json(text: str) -> dict:
    """``json.loads`` that refuses Infinity and NaN (not JSON)."""

    def refuse(name: str) -> float:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def write_csv(path: Path, t_ns: np.ndarray, columns: dict[str, np.ndarray]) -> Path:
    table = np.column_stack([t_ns, *columns.values()])
    header = ",".join(["t_ns", *columns])
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.6f")
    return path


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A CSV of one good echo and the records without one, and a reference from 16
    captures."""
    d = tmp_path_factory.mktemp("no_echo")
    rng = np.random.default_rng(35)
    t = record_axis(PULSE, ARRIVAL_NS)
    captures = records(PULSE, rng, t, ARRIVAL_NS + np.zeros(16), amplitude=0.5, noise=0.005)
    ref = build_reference(captures)
    write_csv(d / "ref.csv", ref.t0_ns + ref.dt_ns * np.arange(ref.n), {"ref": ref.samples})
    good = records(PULSE, rng, t, [ARRIVAL_NS + 1.3], amplitude=0.5, noise=0.01)[0].samples
    late = t[-1] - 1e3 / PULSE.fc_mhz  # a period before the record's end: cut
    cut = records(PULSE, rng, t, [late], amplitude=0.5, noise=0.01)[0].samples
    noise = records(PULSE, rng, t, [ARRIVAL_NS], amplitude=0.0, noise=0.01)[0].samples
    columns = {
        "good": good,
        "noise": noise,
        "zeros": np.zeros(t.size),
        "constant": np.full(t.size, 0.25),
        "cut": cut,
    }
    return write_csv(d / "scans.csv", t, columns), d / "ref.csv"


@pytest.mark.parametrize("with_reference", [True, False])
def test_records_without_an_echo_exit_3_naming_file_and_column(
    cases: tuple[Path, Path], run_main: RunMain, with_reference: bool
) -> None:
    scans, ref = cases
    args = ["echo", str(scans), *(["--reference", str(ref)] if with_reference else [])]
    code, out, err = run_main(args)
    assert code == 3, err
    assert err.startswith(f"error: {scans}: column 'noise': no echo: ")
    assert "and 3 more column(s)" in err
    code, out, err = run_main([*args, "--json"])
    assert code == 3
    result = strict_json(out)
    assert result["exit_code"] == 3 and "column 'noise'" in result["error"]
    echoes = dict(zip(["good", "noise", "zeros", "constant", "cut"], result["echoes"], strict=True))
    assert echoes["good"]["tof_ns"] is not None and "no_echo" not in echoes["good"]
    for name in ("noise", "zeros", "constant", "cut"):
        assert echoes[name]["tof_ns"] is None and echoes[name]["no_echo"], name
    assert "constant" in echoes["zeros"]["no_echo"]
    assert "noise alone" in echoes["noise"]["no_echo"]
    assert "cut by the record's end" in echoes["cut"]["no_echo"]


def test_a_file_of_echoes_keeps_exit_0_and_says_overlapped_and_clipped(
    cases: tuple[Path, Path], run_main: RunMain, tmp_path: Path
) -> None:
    _, ref = cases
    rng = np.random.default_rng(3)
    t = record_axis(PULSE, ARRIVAL_NS)
    clean = records(PULSE, rng, t, [ARRIVAL_NS], amplitude=0.5, noise=0.0)[0].samples
    scans = write_csv(tmp_path / "s.csv", t, {"a": clean, "b": np.clip(4 * clean, -1, 1)})
    code, out, err = run_main(["echo", str(scans), "--reference", str(ref), "--json"])
    assert code == 0, err
    a, b = strict_json(out)["echoes"]  # a: noise-free, its SNR finite (the samples' rounding)
    assert math.isfinite(a["snr_db"]) and a["tof_std_ns"] > 0.0
    assert (a["clipped"], b["clipped"]) == (False, True)
    assert a["overlapped"] is False


def test_clean_records_at_four_samples_a_cycle_are_not_clipped() -> None:
    """Rails unknown (a CSV file): the record's extremes were taken as clipped on 11–15 %
    of clean 25 MHz records at 100 MS/s."""
    rng = np.random.default_rng(8)
    pulse = Pulse(25.0, 100.0)
    t = record_axis(pulse, ARRIVAL_NS)
    ref = build_reference(
        records(pulse, rng, t, ARRIVAL_NS + np.zeros(16), amplitude=0.5, noise=0.005)
    )
    delays = ARRIVAL_NS + rng.uniform(-5.0, 5.0, 150)
    for snr_db in (20.0, 40.0):
        got = records(pulse, rng, t, delays, amplitude=0.5, noise=0.5 * 10 ** (-snr_db / 20))
        clipped = [estimate_echo(AScan(r.t0_ns, r.dt_ns, r.samples), ref).clipped for r in got]
        assert not any(clipped), snr_db


def test_noise_alone_is_no_echo_at_the_false_alarm_rate() -> None:
    rng = np.random.default_rng(21)
    t = record_axis(PULSE, ARRIVAL_NS)
    ref = build_reference(
        records(PULSE, rng, t, ARRIVAL_NS + np.zeros(16), amplitude=0.5, noise=0.005)
    )
    found = 0
    for r in records(PULSE, rng, t, ARRIVAL_NS + np.zeros(200), amplitude=0.0, noise=0.01):
        try:
            estimate_echo(r, ref)
            found += 1
        except NoEcho:
            pass
    assert found <= 2  # 1e-3 a record, Bonferroni: fewer
    inverted = records(PULSE, rng, t, [ARRIVAL_NS], amplitude=-0.5, noise=0.001)[0]
    with pytest.raises(NoEcho, match="inverted"):
        estimate_echo(inverted, ref)


def test_the_hosts_timer_gives_a_record_without_an_echo_no_time() -> None:
    rng = np.random.default_rng(5)
    t = record_axis(PULSE, ARRIVAL_NS)
    ref = build_reference(
        records(PULSE, rng, t, ARRIVAL_NS + np.zeros(16), amplitude=0.5, noise=0.005)
    )
    noise = records(PULSE, rng, t, [ARRIVAL_NS], amplitude=0.0, noise=0.01)[0]
    record = AScanRecord(
        noise.t0_ns, noise.dt_ns, noise.samples, (-1.0, 1.0), 2 / 4096, False, 1, 1, 0.0
    )
    timer = HostEchoTimer(ref)
    echo = timer(record, (float(t[0]), float(t[-1])))
    assert echo.amplitude == 0.0 and math.isnan(echo.tof_ns)
    assert sum(timer.no_echo.values()) == 1 and not timer.timed
