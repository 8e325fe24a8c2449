"""The check of a pulser set by hand against its records (``ucal.echo.by_hand``): the gain the
receiver's noise says, clipping, and an echo's centre frequency, on records drawn here: white
noise of the declared gain's σ (or another), a 12-bit digitiser of ±1 full screen with half a
step of its own front-end noise, and a Gabor echo where asked."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.digitizer.base import AScanRecord, EchoTiming
from ucal.echo.by_hand import GAIN_TOLERANCE_DB, Declared, FirstEchoCheck, judge, look
from ucal.errors import ProfileError

DT_NS = 5.0  # 200 MS/s
N = 8_000  # a 40 µs gate
GATE_NS = (5_000.0, 5_000.0 + N * DT_NS)
LSB = 2.0 / 4096
#: A receiver of 20 µV at 40 dB: σ_p = 2e-3 of full screen, four steps.
DECLARED = Declared(gain_db=40.0, frequency_mhz=10.0, input_noise_uv=20.0, profile="cell.toml")


def record(
    sigma: float,
    seed: int = 0,
    echo: float = 0.0,
    frequency_mhz: float = 10.0,
    front_end_lsb: float = 0.5,
) -> AScanRecord:
    """One record: receiver noise ``sigma`` (fraction of full screen), an echo of peak
    ``echo`` at ``frequency_mhz`` in the middle, the digitiser's own noise and its rounding,
    clipped at ±1."""
    rng = np.random.default_rng(seed)
    t = GATE_NS[0] + DT_NS * np.arange(N)
    x = sigma * rng.standard_normal(N) + front_end_lsb * LSB * rng.standard_normal(N)
    if echo:
        centre = t[N // 2]
        period = 1e3 / frequency_mhz
        x += (
            echo
            * np.exp(-(((t - centre) / (1.5 * period)) ** 2))
            * np.cos(2 * np.pi * (t - centre) / period)
        )
    codes = np.clip(np.rint(x / LSB), -2048, 2047)
    samples = codes * LSB
    clipped = bool(np.any(codes == -2048) or np.any(codes == 2047))
    return AScanRecord(
        GATE_NS[0], DT_NS, samples, (-2048 * LSB, 2047 * LSB), LSB, clipped, 1, seed + 1, 0.0
    )


def records(sigma: float, **kw: float) -> list[AScanRecord]:
    return [record(sigma, seed=k, **kw) for k in range(4)]


def test_records_at_the_declared_gain_pass_and_say_it_within_half_a_db() -> None:
    found = look(records(DECLARED.noise_fsh), DECLARED, GATE_NS)
    assert found.gain == "ok" and found.echo is None and not found.clipped
    assert found.gain_db == pytest.approx(40.0, abs=0.5)
    judge(found, DECLARED)


@pytest.mark.parametrize("true_db", [50.0, 30.0])
def test_a_gain_ten_db_off_is_refused_naming_the_key_and_the_measured_gain(
    true_db: float,
) -> None:
    sigma = DECLARED.noise_fsh * 10 ** ((true_db - 40.0) / 20)
    found = look(records(sigma), DECLARED, GATE_NS)
    assert found.gain == ("higher" if true_db > 40 else "lower")
    with pytest.raises(ProfileError) as refused:
        judge(found, DECLARED)
    message = str(refused.value)
    assert message.startswith("cell.toml: pulser.gain_db: 40 dB, but the A-scans' noise says")
    assert f"{true_db:.0f}." in message and "\n" not in message
    assert found.gain_db == pytest.approx(true_db, abs=1.0)


def test_within_the_tolerance_is_not_refused() -> None:
    sigma = DECLARED.noise_fsh * 10 ** ((GAIN_TOLERANCE_DB - 2.0) / 20)
    found = look(records(sigma), DECLARED, GATE_NS)
    assert found.gain == "ok"
    judge(found, DECLARED)


def test_noise_under_the_step_checks_the_gain_from_above_only() -> None:
    quiet = Declared(gain_db=10.0, frequency_mhz=10.0, input_noise_uv=20.0)  # σ_p = 0.13 step
    found = look(records(quiet.noise_fsh), quiet, GATE_NS)
    assert found.gain == "from above" and found.gain_db is None
    # the gain that would show: the tolerance over a step
    assert found.gain_db_above == pytest.approx(
        10.0 + 20 * math.log10(10 ** (GAIN_TOLERANCE_DB / 20) * LSB / quiet.noise_fsh), abs=1e-9
    )
    judge(found, quiet)  # said, not refused
    # a panel 40 dB above it shows
    loud = look(records(quiet.noise_fsh * 100), quiet, GATE_NS)
    assert loud.gain == "higher"
    with pytest.raises(ProfileError, match=r"pulser\.gain_db: 10 dB, but .* says 50\.\d dB"):
        judge(loud, quiet)


def test_a_clipped_record_is_refused() -> None:
    found = look(records(DECLARED.noise_fsh, echo=1.5), DECLARED, GATE_NS)
    assert found.clipped
    with pytest.raises(ProfileError, match=r"pulser\.gain_db: 40 dB, but .* clipped"):
        judge(found, DECLARED)


def test_an_echo_where_the_arm_stands_gives_its_centre_frequency() -> None:
    found = look(records(DECLARED.noise_fsh, echo=0.5), DECLARED, GATE_NS)
    assert found.echo is not None and found.gain == "ok"
    assert found.echo.centre_frequency_mhz == pytest.approx(10.0, rel=0.02)
    assert found.echo.snr_db > 40
    judge(found, DECLARED)


def test_an_echo_of_another_frequency_is_refused_naming_the_transducer_key() -> None:
    found = look(records(DECLARED.noise_fsh, echo=0.5, frequency_mhz=5.0), DECLARED, GATE_NS)
    with pytest.raises(ProfileError) as refused:
        judge(found, DECLARED)
    message = str(refused.value)
    assert message.startswith("cell.toml: transducer.frequency_mhz: 10 MHz, but the echo")
    assert "centred at 5.0" in message


def test_the_first_timed_echo_is_checked_once_and_its_timing_handed_on() -> None:
    calls = []

    def timer(rec: AScanRecord, gate: tuple[float, float]) -> EchoTiming:
        calls.append(rec.counter)
        return EchoTiming(0.5, 100_000.0, 0.1, "host: reference")

    timer.label = "host: reference"  # type: ignore[attr-defined]
    checked = FirstEchoCheck(timer, DECLARED)
    assert checked.label == "host: reference"  # the timer's attributes
    assert checked(record(DECLARED.noise_fsh, 1, echo=0.5), GATE_NS).tof_ns == 100_000.0
    assert checked.checked
    # once checked, another frequency is the run's to meet, not refused here again
    checked(record(DECLARED.noise_fsh, 2, echo=0.5, frequency_mhz=5.0), GATE_NS)
    assert calls == [2, 3]
    fresh = FirstEchoCheck(timer, DECLARED)
    with pytest.raises(
        ProfileError, match=r"transducer\.frequency_mhz: 10 MHz, but the echo first"
    ):
        fresh(record(DECLARED.noise_fsh, 3, echo=0.5, frequency_mhz=5.0), GATE_NS)
