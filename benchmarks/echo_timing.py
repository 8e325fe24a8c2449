"""Echo timing from the A-scan: the reference estimator against the Cramér–Rao bound and baselines.

Over the grid of issue 22 (60 %-bandwidth echoes at 5–25 MHz, digitised at 100–500 MS/s with
12 bits, 20–40 dB peak SNR) the synthetic digitiser (``ucal.sim.ascan``) gives A-scans of a
ringing, asymmetric echo that is not any estimator's model, each at a random sub-sample
position. Per corner this prints the bound (``true_delay_crb_ns``, from the true echo and
noise) and, for each method, its spread (std of the error) and bias (mean error) against the
true arrival:

* ``reference``: ``ucal.echo.estimate_echo`` against a reference built by
  ``ucal.echo.build_reference`` from ``--averages`` captures at 40 dB with 0.5 ns trigger
  jitter (the cell's commissioning capture), never the noise-free truth; also its reported
  std over the spread;
* ``corr+parabola``: the same correlation, its peak refined by a parabola through three
  samples;
* ``peak gate``: the largest envelope sample of the analytic signal plus a parabola, as the
  simulated pulser's gate does today (``ucal.sim.receiver.EchoReceiver.detect``); its bias is
  mostly where the envelope peaks on this asymmetric echo, not the arrival;
* ``envelope``: ``estimate_echo`` without a reference (the coarse fallback), with its
  reported std over the spread.

Records come in antithetic pairs (the same arrival, opposite noise), so a pair's mean error
holds no first-order noise and the bias is measured to a few thousandths of a ns; the
standard error of each bias is printed beside it. The reference's own error in t = 0 (its
estimate on a noise-free record) is printed per echo and rate: a constant in every time of
flight, which the calibration's electronic delay absorbs.

Usage: python benchmarks/echo_timing.py [--quick] [--pairs 500] [--averages 256] [--json]
(``--quick``: the grid's corners, 100 pairs, 128 averages: a few seconds).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
from scipy import signal

from ucal.echo import ReferenceEcho, build_reference, estimate_echo
from ucal.sim.ascan import (
    Digitiser,
    EchoShape,
    TransducerPulse,
    echo_shape,
    gate_around,
    synthesise,
    true_delay_crb_ns,
)
from ucal.sim.receiver import EchoReceiver

FREQUENCIES_MHZ = (5.0, 15.0, 25.0)
RATES_MHZ = (100.0, 200.0, 500.0)
SNRS_DB = (20.0, 30.0, 40.0)
#: Issue 22, "Done when".
MAX_SPREAD_PER_CRB = 1.3
MAX_BIAS_NS = 0.05
MAX_STD_RATIO = 2.0
AMPLITUDE = 0.5  # of full scale
ARRIVAL_NS = 67_000.0  # 50 mm of water and back
REFERENCE_SNR_DB = 40.0
JITTER_NS = 0.5


def corr_parabola_ns(x: np.ndarray, t0_ns: float, dt_ns: float, ref: ReferenceEcho) -> float:
    """The correlation's largest sample refined by a parabola through it and its neighbours."""
    c = signal.correlate(x - np.mean(x), ref.samples, mode="full", method="fft")
    lags = signal.correlation_lags(x.size, ref.n, mode="full")
    k = int(np.argmax(c))
    a, b, d = c[k - 1], c[k], c[k + 1]
    delta = 0.5 * (a - d) / (a - 2.0 * b + d)
    return t0_ns - ref.t0_ns + (lags[k] + delta) * dt_ns


def stats(errors: np.ndarray) -> tuple[float, float, float]:
    """(spread, bias, standard error of the bias) of antithetic pairs of errors."""
    pairs = errors.reshape(-1, 2).mean(axis=1)
    return float(errors.std()), float(errors.mean()), float(pairs.std() / math.sqrt(pairs.size))


def reference_for(
    shape: EchoShape, rng: np.random.Generator, averages: int
) -> tuple[ReferenceEcho, float]:
    """The cell's reference from ``averages`` noisy captures, and its error in t = 0 (ns)."""
    t0, n = gate_around(shape, ARRIVAL_NS)
    noise = AMPLITUDE * 10 ** (-REFERENCE_SNR_DB / 20)
    captures = synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=ARRIVAL_NS + JITTER_NS * rng.standard_normal(averages),
        amplitude=AMPLITUDE,
        noise_rms=noise,
    )
    ref = build_reference(captures)
    clean = synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=[ARRIVAL_NS],
        amplitude=AMPLITUDE,
        noise_rms=0.0,
    )[0]
    return ref, estimate_echo(clean, ref).tof_ns - ARRIVAL_NS


def corner(
    shape: EchoShape, ref: ReferenceEcho, snr_db: float, pairs: int, rng: np.random.Generator
) -> dict[str, float]:
    """Every method's figures at one SNR."""
    dig = shape.digitiser
    dt = dig.dt_ns
    t0, n = gate_around(shape, ARRIVAL_NS)
    noise = AMPLITUDE * 10 ** (-snr_db / 20)
    arrivals = ARRIVAL_NS + rng.uniform(-0.5, 0.5, pairs) * dt
    records = synthesise(
        shape,
        rng,
        t0_ns=t0,
        n_samples=n,
        arrival_ns=arrivals,
        amplitude=AMPLITUDE,
        noise_rms=noise,
        antithetic=True,
    )
    truth = np.repeat(arrivals, 2)
    gate = EchoReceiver(
        shape.pulse.centre_frequency_mhz, 6.0, sample_rate_hz=dig.sample_rate_mhz * 1e6
    )
    ours, ours_std, parabola, peak, envelope, envelope_std = ([] for _ in range(6))
    for r in records:
        e = estimate_echo(r, ref)
        ours.append(e.tof_ns)
        ours_std.append(e.tof_std_ns)
        parabola.append(corr_parabola_ns(r.samples, r.t0_ns, dt, ref))
        x = r.samples - np.mean(r.samples)
        peak.append(gate.detect(r.t0_ns, signal.hilbert(x))[1])
        f = estimate_echo(r)
        envelope.append(f.tof_ns)
        envelope_std.append(f.tof_std_ns)
    crb = true_delay_crb_ns(shape, AMPLITUDE, noise)
    row = {"crb_ns": crb}
    for name, values in (
        ("reference", ours),
        ("corr_parabola", parabola),
        ("peak_gate", peak),
        ("envelope", envelope),
    ):
        spread, bias, se = stats(np.array(values) - truth)
        row |= {f"{name}_spread_ns": spread, f"{name}_bias_ns": bias, f"{name}_bias_se_ns": se}
    row["reference_std_ratio"] = float(np.mean(ours_std)) / row["reference_spread_ns"]
    row["envelope_std_ratio"] = float(np.mean(envelope_std)) / row["envelope_spread_ns"]
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the grid's corners, fewer records")
    ap.add_argument(
        "--pairs", type=int, help="antithetic pairs per corner (default 500; 100 quick)"
    )
    ap.add_argument("--averages", type=int, help="captures in the reference (256; 128 quick)")
    ap.add_argument("--seed", type=int, default=22)
    ap.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = ap.parse_args(argv)
    pairs = args.pairs or (100 if args.quick else 500)
    averages = args.averages or (128 if args.quick else 256)
    frequencies = (FREQUENCIES_MHZ[0], FREQUENCIES_MHZ[-1]) if args.quick else FREQUENCIES_MHZ
    rates = (RATES_MHZ[0], RATES_MHZ[-1]) if args.quick else RATES_MHZ
    snrs = (SNRS_DB[0], SNRS_DB[-1]) if args.quick else SNRS_DB
    rng = np.random.default_rng(args.seed)
    started = time.perf_counter()
    rows = []
    if not args.json:
        print(
            f"60 % bandwidth echoes, 12 bits, {AMPLITUDE:g} of full scale; {2 * pairs} records "
            f"per corner in antithetic pairs; reference: {averages} captures at "
            f"{REFERENCE_SNR_DB:g} dB, {JITTER_NS:g} ns jitter"
        )
        print(
            f"{'f_c':>4} {'MS/s':>4} {'SNR':>3} {'CRB ns':>7} | {'reference: spread/CRB':>21} "
            f"{'bias ns':>16} {'std/spread':>10} | {'corr+parabola: /CRB':>19} {'bias ns':>7} | "
            f"{'peak gate: /CRB':>15} {'bias ns':>7} | {'envelope: /CRB':>14} {'std/spread':>10}"
        )
    for fc in frequencies:
        for rate in rates:
            shape = echo_shape(TransducerPulse(fc), Digitiser(rate, 12, 1.0))
            ref, ref_error = reference_for(shape, rng, averages)
            if not args.json:
                print(f"{fc:4g} {rate:4g}  reference's error in t = 0: {ref_error:+.4f} ns")
            for snr in snrs:
                row = {"frequency_mhz": fc, "sample_rate_mhz": rate, "snr_db": snr}
                row |= {"reference_t0_error_ns": ref_error}
                row |= corner(shape, ref, snr, pairs, rng)
                rows.append(row)
                if not args.json:
                    crb = row["crb_ns"]
                    print(
                        f"{fc:4g} {rate:4g} {snr:3g} {crb:7.4f} | "
                        f"{row['reference_spread_ns'] / crb:21.3f} "
                        f"{row['reference_bias_ns']:+8.4f}±{row['reference_bias_se_ns']:.4f} "
                        f"{row['reference_std_ratio']:10.3f} | "
                        f"{row['corr_parabola_spread_ns'] / crb:19.2f} "
                        f"{row['corr_parabola_bias_ns']:+7.3f} | "
                        f"{row['peak_gate_spread_ns'] / crb:15.2f} "
                        f"{row['peak_gate_bias_ns']:+7.2f} | "
                        f"{row['envelope_spread_ns'] / crb:14.2f} {row['envelope_std_ratio']:10.3f}"
                    )
    worst_spread = max(r["reference_spread_ns"] / r["crb_ns"] for r in rows)
    worst_bias = max(abs(r["reference_bias_ns"]) for r in rows)
    ratios = [r["reference_std_ratio"] for r in rows]
    ok = (
        worst_spread <= MAX_SPREAD_PER_CRB
        and worst_bias <= MAX_BIAS_NS
        and all(1 / MAX_STD_RATIO <= q <= MAX_STD_RATIO for q in ratios)
    )
    summary = {
        "worst_spread_per_crb": worst_spread,
        "worst_abs_bias_ns": worst_bias,
        "std_ratio_range": [min(ratios), max(ratios)],
        "meets_issue_22": ok,
        "seconds": time.perf_counter() - started,
    }
    if args.json:
        print(json.dumps({"corners": rows, "summary": summary}))
    else:
        print(
            f"reference estimator: spread ≤ {worst_spread:.3f} × CRB (issue 22: ≤ "
            f"{MAX_SPREAD_PER_CRB}), |bias| ≤ {worst_bias:.4f} ns (≤ {MAX_BIAS_NS}), reported "
            f"std / spread {min(ratios):.2f}…{max(ratios):.2f} (within ×{MAX_STD_RATIO:g}): "
            f"{'met' if ok else 'NOT met'}; {summary['seconds']:.1f} s"
        )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
