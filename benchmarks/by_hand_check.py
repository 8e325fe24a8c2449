"""The check of a pulser set by hand (``ucal.echo.by_hand``) against panels not as declared.

Through the path a run takes (the simulated cell of ``ucal sim serve`` with a pulser set by
hand, its oscilloscope over VISA, ``drivers.pulser.manual.ManualPulser``, then
``records_at_the_panel`` and ``look``), a tx90l profile declaring a panel at 20 dB and a 25 MHz
transducer meets worlds whose panel is at another gain or whose transducer has another
frequency:

* the gain: the arm at its zero posture (beam in open water), the panel's true gain over
  ``--gains``, the oscilloscope's ADC over ``--bits``, ``--seeds`` noise draws each: the gain
  the records' noise says (median and range over the seeds; "under step" where the declared
  gain's noise is under the digitiser's step and the records show only the digitiser's own)
  and the verdicts (ok, higher, lower, from above; "clipped" where a sample sat on a rail);
* the frequency: the arm standing over the block (the profile's calibration pose, the beam
  straight down on the XY face), the true transducer over ``--frequencies``: the echo's centre
  frequency (the middle of its −6 dB band) and whether the check refuses it (beyond ±25 % of
  the declared 25 MHz).

Usage: python benchmarks/by_hand_check.py [--gains 14,20,...] [--bits 8,12] [--seeds 4]
  [--frequencies 5,10,15,20,25] (``--quick``: 20 and 60 dB, 12 bits, one seed, 15 and 25 MHz:
  a few seconds).
"""

from __future__ import annotations

import argparse
import logging
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from _quick import parse_args

from drivers.pulser.manual import ManualPulser
from ucal.cell import CellProfile, WorldTruth
from ucal.devices.rig import DEFAULT_SETTINGS
from ucal.echo.by_hand import Findings, judge, look, records_at_the_panel
from ucal.errors import ProfileError
from ucal.profile import default_profile_text, load_profile
from ucal.profile.by_hand import declared_of
from ucal.sim.serve import SimulatedCellServer

#: The profile's calibration pose: the beam straight down on the block's XY face.
FACING_THE_BLOCK = np.array([30.53, 31.15, 109.49, 0.0, 39.36, 30.54])
PANEL = '\n[pulser]\nkind = "manual"\ngain_db = 20.0\nprf_hz = 500.0\n'
QUICK = {"gains": "20,60", "bits": "12", "seeds": 1, "frequencies": "15,25"}


def numbers(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v.strip()]


def looked(profile: CellProfile, world: WorldTruth) -> tuple[Findings, str]:
    """What the check finds in the records of ``world``'s cell where the arm stands, and its
    verdict (``"ok"`` or the key it refuses)."""
    with SimulatedCellServer(world, profile, time_scale=0.0) as cell:
        assert profile.pulser.by_hand is not None
        pulser = ManualPulser(cell.urls["digitizer"], profile.pulser.by_hand.panel)
        with pulser:
            declared = declared_of(profile, pulser.full_screen_v)
            records, gate_ns = records_at_the_panel(pulser, declared, DEFAULT_SETTINGS)
    found = look(records, declared, gate_ns)
    try:
        judge(found, declared)
        verdict = "ok"
    except ProfileError as e:
        verdict = "refused: " + str(e.key)
    return found, verdict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gains", default="14,20,26,34,40,46,53,60")
    ap.add_argument("--bits", default="8,12")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--frequencies", default="5,10,15,20,25")
    ap.add_argument("--quick", action="store_true", help="a few cells: the same code path")
    args = parse_args(ap, QUICK)
    logging.getLogger("ucal.echo.by_hand").setLevel(logging.ERROR)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cell.toml"
        path.write_text(default_profile_text("tx90l") + PANEL)
        profile = load_profile(path)
    nominal = WorldTruth.nominal(profile)
    print("declared: 20 dB, 25 MHz, input noise 2.2 µV; the digitiser ±1 V full screen")
    print(f"{'bits':>4} {'true dB':>7} {'noise says dB':>22}  gain verdicts (check)")
    for bits in numbers(args.bits):
        for gain in numbers(args.gains):
            said, verdicts, checks = [], [], []
            for seed in range(args.seeds):
                world = nominal.replace(
                    pulser=replace(nominal.pulser, gain_db=gain, bits=int(bits)),
                    noise=replace(nominal.noise, seed=seed + 1),
                )
                found, verdict = looked(profile, world)
                if found.gain_db is not None:
                    said.append(found.gain_db)
                verdicts.append("clipped" if found.clipped else found.gain)
                checks.append(verdict)
            shown = (
                f"{np.median(said):6.1f} ({min(said):5.1f}…{max(said):5.1f})"
                if said
                else "under step"
            )
            tally = ", ".join(f"{v} {verdicts.count(v)}" for v in sorted(set(verdicts)))
            refused = sum(c != "ok" for c in checks)
            print(
                f"{int(bits):>4} {gain:>7.0f} {shown:>22}  {tally} "
                f"({refused}/{len(checks)} refused)"
            )
    print(f"{'true MHz':>8} {'echo centre MHz':>16}  check")
    for frequency in numbers(args.frequencies):
        world = nominal.replace(frequency_mhz=frequency, initial_joints_deg=FACING_THE_BLOCK)
        found, verdict = looked(profile, world)
        echo = found.echo
        centre = "no echo" if echo is None else f"{echo.centre_frequency_mhz:.2f}"
        print(f"{frequency:>8.1f} {centre:>16}  {verdict}")


if __name__ == "__main__":
    main()
