"""World files: the truth the simulator is told (SPEC.md, "World file").

Every key is optional. A missing key means "as the profile says" (nominal = true), zero joint
offsets, zero noise; for the tool, the block and the kinematic model, as the profile describes
them, not as ucal measured them (``CellProfile.as_described``: the tool as drawn, the block as
placed, the ``[robot]`` table): the truth does not move with the estimates ``tool-frame`` and
``calibrate`` write. Values use the profile's units (mm, deg,
°C, MHz) and the same validators, so an error names the world file and the dotted key. Keys
the solvers do not model:

* ``[robot] dh`` rows may carry ``beta_deg`` (Hayati's twist about the link's y axis,
  ``A_i = Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)``, |β| <= 30°; an array row may give it as a fifth
  number); stored as ``WorldTruth.dh_beta_deg``;
* ``[robot] backlash_deg = [6]`` — lost motion per joint (0…5°): the link lags the encoder by
  half of it, against the direction of the joint's last motion;
* ``[robot] repeatability_deg = [6]`` — one sigma (0…0.1°) of where each link settles after
  a move of its joint, about where its encoder says: drawn anew for every move (seeded by
  ``[noise] seed``), never seen in the readings; the arm's pose repeatability (ISO 9283 RP);
* the arm as it bends under gravity and grows as it warms (``ucal.world_arm``):
  ``[robot] stiffness_nm_per_rad``, ``link_mass_kg``, ``link_centre_of_mass_mm``,
  ``gravity_m_s2``; ``[tool] mass_kg``, ``centre_of_mass_mm``; ``[arm] offset_k``,
  ``warmup_k``, ``warmup_time_constant_min``, ``expansion_per_k``;
* ``[water] drift_c_per_min`` — the tank warms (+) or cools linearly in simulated time
  (|drift| <= 10 °C/min; ``temperature_c`` is the temperature at the start of the run);
  ``temperature_log`` — in place of both, what the tank's thermometer read over the run: a
  CSV file (relative to the world file) of rows ``minutes,°C``, the minutes of simulated time
  since the cell started (the drift's time base), strictly increasing, 0–60 °C; an optional
  first line ``time_min,temperature_c``, blank lines and ``#`` comments are skipped; at least
  one row. The water follows the straight line between readings and stays at the first
  (last) reading before (after) them (:class:`ucal.thermometer.TemperatureLog`);
  ``absorption = true`` — every echo of an A-scan shaped by water's absorption α₀(T)·f² over
  its own water path, both ways: its spectrum moves down and it broadens with the path
  (``ucal.sim.rf``; default false, every echo of one shape);
* ``[pulser] amplitude_bits`` (0…24; 0 = not quantised), ``gain_error_db`` (one sigma, 0…6 dB)
  and ``delay_ns`` (fixed electronic delay in every TOF, −1000…10 000 ns, default
  ``ucal.cell.DEFAULT_PULSER_DELAY_NS`` = 8 ns) — see :class:`ucal.cell.PulserTruth`;
  ``register_map`` — the Modbus register map file the simulated pulser serves (relative to the
  world file; default: the profile's ``[pulser] register_map``, else ucal's own map);
  ``kind`` — the back-end the simulated cell speaks: ``"modbus"`` (default) or ``"ascii-scpi"``
  (an ASCII serial pulser and a SCPI oscilloscope, ``ucal.sim.serve``), whose digitiser samples
  at ``sample_rate_mhz`` (10…5000, default 200) with a ``bits`` ADC (8…16, default 12);
  ``scope`` — that oscilloscope's family, the dialect it speaks: ``"keysight"`` (default, an
  InfiniiVision X-Series) or ``"rigol"`` (a DS1000Z, whose ADC has 8 bits whatever ``bits``
  says); ``drivers.digitizer.simulated_scopes.FAMILIES``; ``"manual"`` (the default of a
  profile whose pulser is set by hand): that oscilloscope alone beside a pulser-receiver set by
  hand, whose front panel's true gain is ``gain_db`` (default: the profile's declaration) and
  whose echoes' centre frequency is the world's ``[transducer] frequency_mhz``;
  ``baseline_offset`` — the receiver's output at rest (−0.5…0.5 of full screen height), a
  constant in every A-scan sample, in its averages and in the reference echo a run captures;

Extra keys beyond SPEC.md:

* ``[robot] initial_joints_deg`` — joint readings (deg) the simulated robot starts at;
* ``[sample] face_size_mm`` — edge length of the block faces (mm);
* ``[step]`` ``height_mm``, ``centre_mm``, ``size_mm`` — the step on the block's XY face as it
  really is; ``tilt_deg`` = [about x, about y] (up to 1 deg) — its top not quite parallel to the
  face (see ``ucal.cell.Step``);
* ``[reflector] size_mm = [w, h]`` and ``edge_direction = [x, y, z]`` — extent of the plate;
  ``edge_radius_mm`` (0…20: rounded edges, the flat part ends that far inside) and
  ``flatness_mm`` (0…5, peak to valley: a bow along the normal) — see ``ucal.cell.Reflector``;
* ``[transducer] squint_deg`` (0…5) and ``squint_azimuth_deg`` — the acoustic axis tilted from
  the housing's z axis (the tool frame of the drawing); ``near_field = true`` — near-field
  directivity (``ucal.sim.receiver``).
* ``[controller] server`` — the Simple Message server the simulated controller behaves as
  (``drivers.controller.simulator.SERVERS``: ``"simple"``, the default; ``"val3"``, the
  released VAL3 server; ``"val3-feedback"``, its 250 Hz JOINT_FEEDBACK pull request), and
  ``startup_silence_s`` to change that server's silence after a client connects (0…60 s).
* ``[timing]`` — the real cell's time (``ucal.cell.CellTiming``): ``state_period_ms`` (the
  state stream's period; default 20, the released VAL3 server's 50 Hz), ``state_latency_ms``
  and ``state_jitter_ms`` (how late a frame's position arrives; 2 and 1), ``missing_state_frames``
  (share lost, 0…0.5; 0), ``pulser_latency_ms`` and ``pulser_jitter_ms`` (the instrument
  transport's round trip beyond its turnaround; 1 and 0.5), ``acquisition_delay_ms`` (from the
  acquisition to the reply that carries it; 0). Applied on the simulated and the host clock.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from drivers.controller.simulator import SERVERS
from drivers.digitizer.simulated_scopes import FAMILIES as SCOPE_FAMILIES
from ucal.cell import (
    CellProfile,
    CellTiming,
    Noise,
    PulserTruth,
    Reflector,
    TemperatureLog,
    WorldTruth,
)
from ucal.profile import (
    read_robot,
    read_step,
    read_transducer,
    read_water,
)
from ucal.profile.validation import (
    Reader,
    describe_unknown,
    read_toml,
    refuse_misspelt_keys,
    unknown_keys,
)
from ucal.thermometer import read_log
from ucal.world_arm import ARM_KEYS, ROBOT_KEYS, TOOL_KEYS, read_arm

#: Keys a world file may hold (others are reported by :func:`world_warnings`; one that is a
#: misspelling of a known key the table lacks is refused).
KNOWN_WORLD_KEYS: dict[str, frozenset[str] | None] = {
    "": frozenset(),
    "robot": frozenset(
        {
            "model",
            "dh",
            "joint_min_deg",
            "joint_max_deg",
            "joint_offsets_deg",
            "initial_joints_deg",
            "backlash_deg",
            "repeatability_deg",
            *ROBOT_KEYS,
        }
    ),
    "tool": frozenset({"position_mm", "rotation_deg", *TOOL_KEYS}),
    "arm": ARM_KEYS,
    "sample": frozenset({"position_mm", "rotation_deg", "face_size_mm"}),
    "step": frozenset({"height_mm", "centre_mm", "size_mm", "tilt_deg"}),
    "reflector": frozenset(
        {"point_mm", "normal", "size_mm", "edge_direction", "edge_radius_mm", "flatness_mm"}
    ),
    "water": frozenset({"temperature_c", "drift_c_per_min", "temperature_log", "absorption"}),
    "transducer": frozenset(
        {"frequency_mhz", "element_diameter_mm", "squint_deg", "squint_azimuth_deg", "near_field"}
    ),
    "pulser": frozenset(
        {
            "amplitude_bits",
            "gain_error_db",
            "delay_ns",
            "register_map",
            "kind",
            "sample_rate_mhz",
            "bits",
            "scope",
            "gain_db",
            "baseline_offset",
        }
    ),
    "noise": frozenset({"tof_ns", "amplitude", "seed"}),
    "controller": frozenset({"server", "startup_silence_s"}),
    "timing": frozenset(
        {
            "state_period_ms",
            "state_latency_ms",
            "state_jitter_ms",
            "missing_state_frames",
            "pulser_latency_ms",
            "pulser_jitter_ms",
            "acquisition_delay_ms",
        }
    ),
}

#: Largest Hayati twist (deg), backlash (deg) and water drift (°C/min) a world file may state.
MAX_BETA_DEG = 30.0
MAX_BACKLASH_DEG = 5.0
#: Largest scatter of a link's settled position a world may state (deg, one sigma).
MAX_REPEATABILITY_DEG = 0.1
MAX_DRIFT_C_PER_MIN = 10.0
#: Largest beam squint (deg), plate edge radius (mm) and flatness error (mm) a world may state.
MAX_SQUINT_DEG = 5.0
MAX_EDGE_RADIUS_MM = 20.0
MAX_FLATNESS_MM = 5.0
#: Largest baseline offset of the receiver's output a world may state (fraction of full screen).
MAX_BASELINE_OFFSET = 0.5


def load_world(path: str | Path | None, profile: CellProfile) -> WorldTruth:
    """The simulator's truth: the world file at ``path`` over the nominal world of the profile
    as described (module docstring).

    ``path=None`` gives the nominal world (no hidden error, no noise). Raises
    :class:`ucal.errors.ProfileError` (exit 2) naming the world file and the key.
    """
    world = WorldTruth.nominal(profile.as_described())
    if path is None:
        return world
    p = Path(path)
    return world_from_data(read_toml(p), p, profile)


def world_warnings(path: str | Path) -> list[str]:
    """Keys of a world file that the simulator does not know (usually typos)."""
    data = read_toml(path).unwrap()
    return [describe_unknown(k, KNOWN_WORLD_KEYS) for k in unknown_keys(data, KNOWN_WORLD_KEYS)]


def world_from_data(data: Mapping[str, Any], path: str | Path, profile: CellProfile) -> WorldTruth:
    """Validate parsed world data (tomlkit document or dict) over the profile's nominal world."""
    if hasattr(data, "unwrap"):
        data = data.unwrap()
    r = Reader(path, data)
    refuse_misspelt_keys(r, KNOWN_WORLD_KEYS)  # else ignored: the truth would silently be nominal
    world = WorldTruth.nominal(profile.as_described())
    changes: dict[str, Any] = {}

    robot = r.table("robot")
    if robot is not None:
        robot, beta = _split_beta(r, robot)
        if beta is not None:
            changes["dh_beta_deg"] = beta
        if "model" in robot or "dh" in robot:
            changes["model"] = read_robot(r, robot, "robot", ranges_from=profile.model)
        elif "joint_min_deg" in robot or "joint_max_deg" in robot:
            raise r.error(
                "robot.joint_min_deg",
                "joint ranges need a model or dh table here "
                "(they are taken from the profile otherwise)",
            )
        model = changes.get("model", world.model)
        v = r.get(robot, "robot.joint_offsets_deg")
        if v is not None:
            changes["joint_offsets_deg"] = r.joint_offsets("robot.joint_offsets_deg", v)
        v = r.get(robot, "robot.initial_joints_deg")
        if v is not None:
            changes["initial_joints_deg"] = r.joints_within(
                "robot.initial_joints_deg", v, model.joint_min_deg, model.joint_max_deg
            )
        v = r.get(robot, "robot.backlash_deg")
        if v is not None:
            changes["backlash_deg"] = r.vector(
                "robot.backlash_deg", v, 6, lo=0.0, hi=MAX_BACKLASH_DEG, unit="deg"
            )
        v = r.get(robot, "robot.repeatability_deg")
        if v is not None:
            changes["repeatability_deg"] = r.vector(
                "robot.repeatability_deg", v, 6, lo=0.0, hi=MAX_REPEATABILITY_DEG, unit="deg"
            )

    tool = r.table("tool")
    arm = read_arm(r, robot, tool, r.table("arm"), changes.get("model", world.model))
    if arm is not None:
        changes["arm"] = arm
    _vector(r, tool, "tool", "position_mm", 3, "mm", changes, "tool_position_mm")
    _vector(r, tool, "tool", "rotation_deg", 3, "deg", changes, "tool_rotation_deg")

    sample = r.table("sample")
    _vector(r, sample, "sample", "position_mm", 3, "mm", changes, "sample_position_mm")
    _vector(r, sample, "sample", "rotation_deg", 3, "deg", changes, "sample_rotation_deg")
    v = r.get(sample, "sample.face_size_mm")
    if v is not None:
        changes["sample_face_size_mm"] = r.number(
            "sample.face_size_mm", v, lo=0.0, lo_open=True, unit="mm"
        )

    reflector = r.table("reflector")
    if reflector is not None:
        changes["reflector"] = _reflector(r, reflector, world.reflector)

    step = r.table("step")
    if step is not None:
        face_mm = changes.get("sample_face_size_mm", world.sample_face_size_mm)
        changes["step"] = read_step(r, step, face_mm, world.step, profile=False)

    water = r.table("water")
    v = r.get(water, "water.temperature_log")
    if water is not None and v is not None:
        log = _temperature_log(r, water, v)
        changes["water_temperature_log"] = log
        changes["water_temperature_c"] = log.at(0.0)
    water_c = read_water(r, water, "water", required=False)
    if water_c is not None:
        changes["water_temperature_c"] = water_c
    v = r.get(water, "water.drift_c_per_min")
    if v is not None:
        changes["water_drift_c_per_min"] = r.number(
            "water.drift_c_per_min",
            v,
            lo=-MAX_DRIFT_C_PER_MIN,
            hi=MAX_DRIFT_C_PER_MIN,
            unit="degC/min",
        )
    v = r.get(water, "water.absorption")
    if v is not None:
        changes["water_absorption"] = r.flag("water.absorption", v)
    transducer = r.table("transducer")
    freq, diam = read_transducer(r, transducer, "transducer", required=False)
    if freq is not None:
        changes["frequency_mhz"] = freq
    if diam is not None:
        changes["element_diameter_mm"] = diam
    v = r.get(transducer, "transducer.squint_deg")
    if v is not None:
        changes["beam_squint_deg"] = r.number(
            "transducer.squint_deg", v, lo=0.0, hi=MAX_SQUINT_DEG, unit="deg"
        )
    v = r.get(transducer, "transducer.squint_azimuth_deg")
    if v is not None:
        changes["beam_squint_azimuth_deg"] = r.number(
            "transducer.squint_azimuth_deg", v, lo=-360.0, hi=360.0, unit="deg"
        )
    v = r.get(transducer, "transducer.near_field")
    if v is not None:
        changes["near_field"] = r.flag("transducer.near_field", v)

    pulser = r.table("pulser")
    if pulser is not None:
        changes["pulser"] = _pulser(r, pulser, world.pulser)

    controller = r.table("controller")
    v = r.get(controller, "controller.server")
    if v is not None:
        server = r.string("controller.server", v)
        if server not in SERVERS:
            raise r.error(
                "controller.server", f"unknown server {server!r} (known: {', '.join(SERVERS)})"
            )
        changes["controller_server"] = server
    v = r.get(controller, "controller.startup_silence_s")
    if v is not None:
        changes["controller_silence_s"] = r.number(
            "controller.startup_silence_s", v, lo=0.0, hi=60.0, unit="s"
        )

    timing_table = r.table("timing")
    if timing_table is not None:
        changes["timing"] = _timing(r, timing_table)

    noise = r.table("noise")
    if noise is not None:
        d = Noise()
        tof = r.get(noise, "noise.tof_ns")
        amp = r.get(noise, "noise.amplitude")
        seed = r.get(noise, "noise.seed")
        changes["noise"] = Noise(
            tof_ns=d.tof_ns
            if tof is None
            else r.number("noise.tof_ns", tof, lo=0.0, hi=1000.0, unit="ns"),
            amplitude=d.amplitude
            if amp is None
            else r.number("noise.amplitude", amp, lo=0.0, hi=10.0),
            seed=d.seed if seed is None else r.integer("noise.seed", seed, lo=0, hi=2**63 - 1),
        )
    return world.replace(**changes)


def _temperature_log(r: Reader, water: Mapping[str, Any], value: Any) -> TemperatureLog:
    """``[water] temperature_log``: a CSV file (relative to the world file) of the tank
    thermometer's readings, one ``minutes,°C`` row each (module docstring). It replaces
    ``temperature_c`` and ``drift_c_per_min``, which may not be given with it."""
    key = "water.temperature_log"
    for other in ("temperature_c", "drift_c_per_min"):
        if other in water:
            raise r.error(
                f"water.{other}",
                f"not with {key}: the log gives the water's temperature over the run",
            )
    p = Path(r.string(key, value)).expanduser()
    if not p.is_absolute():
        p = r.path.parent / p
    return read_log(p, f"{key} in {r.path}", wall_clock=False)


def _split_beta(r: Reader, robot: Mapping[str, Any]) -> tuple[Mapping[str, Any], np.ndarray | None]:
    """Take the optional Hayati ``beta_deg`` out of ``[robot] dh``: the table without it (for
    the profile's DH reader) and the six twists (deg), or None when there is no ``dh``."""
    raw = robot.get("dh")
    if raw is None:
        return robot, None
    stripped, beta = r.split_beta("robot.dh", raw, MAX_BETA_DEG)
    return {**robot, "dh": stripped}, beta


#: Bounds of the ``[timing]`` keys (ms, or a share): a state period of a 1 kHz stream to 1 s, a
#: latency or delay up to a second.
_TIMING_MS_BOUNDS = {
    "state_period_ms": (1.0, 1000.0),
    "state_latency_ms": (0.0, 1000.0),
    "state_jitter_ms": (0.0, 1000.0),
    "pulser_latency_ms": (0.0, 1000.0),
    "pulser_jitter_ms": (0.0, 1000.0),
    "acquisition_delay_ms": (0.0, 1000.0),
}


def _timing(r: Reader, table: Mapping[str, Any]) -> CellTiming:
    """``[timing]``: the real cell's time (ms in the file, s in ``CellTiming``)."""
    d = CellTiming()
    values: dict[str, float] = {}
    for key, (lo, hi) in _TIMING_MS_BOUNDS.items():
        v = r.get(table, f"timing.{key}")
        if v is not None:
            values[key.removesuffix("_ms") + "_s"] = 1e-3 * r.number(
                f"timing.{key}", v, lo=lo, hi=hi, unit="ms"
            )
    v = r.get(table, "timing.missing_state_frames")
    if v is not None:
        values["missing_state_frames"] = r.number("timing.missing_state_frames", v, lo=0.0, hi=0.5)
    return replace(d, **values)


#: The back-ends a simulated cell may speak (``[pulser] kind``).
PULSER_KINDS = ("modbus", "ascii-scpi", "manual")


def _pulser(r: Reader, table: Mapping[str, Any], d: PulserTruth) -> PulserTruth:
    """``[pulser]`` over ``d`` (the profile's): amplitude_bits (0…24), gain_error_db (0…6 dB),
    delay_ns (−1000…10 000), register_map (a map file relative to the world file), kind
    (``PULSER_KINDS``), sample_rate_mhz (10…5000) and bits (8…16) of the digitiser, scope (its
    family), gain_db (a pulser set by hand's front panel, −20…100 dB), baseline_offset (the
    receiver's output at rest, −0.5…0.5 of full screen)."""
    kind_raw = r.get(table, "pulser.kind")
    kind = d.kind if kind_raw is None else r.string("pulser.kind", kind_raw)
    if kind not in PULSER_KINDS:
        raise r.error("pulser.kind", f"unknown kind {kind!r} (known: {', '.join(PULSER_KINDS)})")
    scope_raw = r.get(table, "pulser.scope")
    scope = d.scope if scope_raw is None else r.string("pulser.scope", scope_raw)
    if scope not in SCOPE_FAMILIES:
        raise r.error(
            "pulser.scope", f"unknown scope family {scope!r} (known: {', '.join(SCOPE_FAMILIES)})"
        )
    rate = r.get(table, "pulser.sample_rate_mhz")
    adc_bits = r.get(table, "pulser.bits")
    bits = r.get(table, "pulser.amplitude_bits")
    gain = r.get(table, "pulser.gain_error_db")
    delay = r.get(table, "pulser.delay_ns")
    panel = r.get(table, "pulser.gain_db")
    offset = r.get(table, "pulser.baseline_offset")
    if panel is not None and kind != "manual":
        raise r.error(
            "pulser.gain_db",
            f'is the front panel\'s gain of a pulser set by hand (kind = "manual"): the {kind} '
            "pulser's gain is the one ucal sets",
        )
    map_raw = r.get(table, "pulser.register_map")
    map_path, register_map = (
        (None, None) if map_raw is None else r.register_map("pulser.register_map", map_raw)
    )
    return PulserTruth(
        register_map_path=map_path,
        register_map=register_map,
        amplitude_bits=d.amplitude_bits
        if bits is None
        else r.integer("pulser.amplitude_bits", bits, lo=0, hi=24),
        gain_error_db=d.gain_error_db
        if gain is None
        else r.number("pulser.gain_error_db", gain, lo=0.0, hi=6.0, unit="dB"),
        delay_ns=d.delay_ns
        if delay is None
        else r.number("pulser.delay_ns", delay, lo=-1000.0, hi=10000.0, unit="ns"),
        kind=kind,
        sample_rate_mhz=d.sample_rate_mhz
        if rate is None
        else r.number("pulser.sample_rate_mhz", rate, lo=10.0, hi=5000.0, unit="MHz"),
        bits=d.bits if adc_bits is None else r.integer("pulser.bits", adc_bits, lo=8, hi=16),
        scope=scope,
        gain_db=d.gain_db
        if panel is None
        else r.number("pulser.gain_db", panel, lo=-20.0, hi=100.0, unit="dB"),
        baseline_offset=d.baseline_offset
        if offset is None
        else r.number(
            "pulser.baseline_offset", offset, lo=-MAX_BASELINE_OFFSET, hi=MAX_BASELINE_OFFSET
        ),
    )


def _vector(
    r: Reader,
    table: Mapping[str, Any] | None,
    tname: str,
    key: str,
    n: int,
    unit: str,
    changes: dict[str, Any],
    field_name: str,
) -> None:
    v = r.get(table, f"{tname}.{key}")
    if v is not None:
        changes[field_name] = r.vector(f"{tname}.{key}", v, n, unit=unit)


def _reflector(r: Reader, table: Mapping[str, Any], nominal: Reflector | None) -> Reflector:
    """``[reflector]``: point_mm (mm), normal (unit vector, towards the water side), optional
    size_mm = [w, h] (mm, > 0) and edge_direction (not parallel to the normal)."""
    required = nominal is None  # no plate in the profile: the world must define one
    point_raw = r.get(table, "reflector.point_mm", required)
    normal_raw = r.get(table, "reflector.normal", required)
    # with no nominal plate both keys were required above: the nominal is read only if it exists
    point = (
        r.vector("reflector.point_mm", point_raw, 3, unit="mm")
        if point_raw is not None or nominal is None
        else nominal.point_mm
    )
    normal = (
        r.direction("reflector.normal", normal_raw)
        if normal_raw is not None or nominal is None
        else nominal.normal
    )
    base = nominal if nominal is not None else Reflector(point_mm=point, normal=normal)
    size_raw = r.get(table, "reflector.size_mm")
    size = (
        base.size_mm
        if size_raw is None
        else r.vector("reflector.size_mm", size_raw, 2, lo=0.0, lo_open=True, unit="mm")
    )
    edge_raw = r.get(table, "reflector.edge_direction")
    edge = (
        base.edge_direction
        if edge_raw is None
        else r.direction("reflector.edge_direction", edge_raw)
    )
    if np.linalg.norm(np.cross(edge, normal)) < 1e-6:
        key = "reflector.edge_direction" if edge_raw is not None else "reflector.normal"
        raise r.error(key, "edge_direction must not be parallel to the normal")
    radius_raw = r.get(table, "reflector.edge_radius_mm")
    radius = (
        base.edge_radius_mm
        if radius_raw is None
        else r.number(
            "reflector.edge_radius_mm", radius_raw, lo=0.0, hi=MAX_EDGE_RADIUS_MM, unit="mm"
        )
    )
    if 2.0 * radius >= float(np.min(size)):
        raise r.error(
            "reflector.edge_radius_mm",
            "leaves no flat plate: it must be below half the plate's size",
        )
    flat_raw = r.get(table, "reflector.flatness_mm")
    flatness = (
        base.flatness_mm
        if flat_raw is None
        else r.number("reflector.flatness_mm", flat_raw, lo=0.0, hi=MAX_FLATNESS_MM, unit="mm")
    )
    return Reflector(
        point_mm=np.asarray(point, float),
        normal=np.asarray(normal, float),
        size_mm=np.asarray(size, float),
        edge_direction=np.asarray(edge, float),
        edge_radius_mm=float(radius),
        flatness_mm=float(flatness),
    )
