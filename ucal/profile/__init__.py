"""Cell profiles: load and validate, create from a shipped model, write results, undo.

A profile (SPEC.md, "Profile file") is a commented TOML file the technician owns. ucal reads it
with tomlkit and writes results back into it with tomlkit, so comments and key order survive.
Writes are atomic and reversible: each keeps the bytes it replaces in the profile's history.

- :mod:`ucal.profile.read`: read and validate a profile (and the tables a world file shares);
- :mod:`ucal.profile.calibration`: ``[calibration]`` as typed records, written and read back;
- :mod:`ucal.profile.validation`: the TOML reader and key checks every input file goes through;
- :mod:`ucal.profile.template`: the text of a new profile, ``template.toml`` filled in;
- :mod:`ucal.profile.write`: write results into a profile, create a new one;
- :mod:`ucal.profile.history`: the history of a profile's writes, undo;
- :mod:`ucal.profile.described`: the cell as described, kept beside what ucal measured;
- :mod:`ucal.profile.lock`: one run at a time on a profile, room to write it;
- :mod:`ucal.profile.disk`: where a profile's files sit, atomic replacement.
"""

from ucal.profile.described import description_keys, pose_digest
from ucal.profile.disk import history_dir, made_history_dir, real_path
from ucal.profile.history import (
    HistoryEntry,
    last_measurement,
    profile_history,
    undo_profile,
)
from ucal.profile.lock import check_writable, lock_path, profile_lock
from ucal.profile.read import (
    DEFAULT_FACE_MM,
    load_profile,
    profile_from_data,
    profile_from_text,
    profile_to_dict,
    profile_warnings,
    read_robot,
    read_step,
    read_tolerances,
    read_transducer,
    read_water,
)
from ucal.profile.template import (
    EXAMPLE_HEADER,
    EXAMPLE_MODEL,
    default_profile_text,
    example_profile_text,
)
from ucal.profile.write import create_profile, write_profile

__all__ = [
    "DEFAULT_FACE_MM",
    "EXAMPLE_HEADER",
    "EXAMPLE_MODEL",
    "HistoryEntry",
    "check_writable",
    "create_profile",
    "default_profile_text",
    "description_keys",
    "example_profile_text",
    "history_dir",
    "last_measurement",
    "load_profile",
    "lock_path",
    "made_history_dir",
    "pose_digest",
    "profile_from_data",
    "profile_from_text",
    "profile_history",
    "profile_lock",
    "profile_to_dict",
    "profile_warnings",
    "read_robot",
    "read_step",
    "read_tolerances",
    "read_transducer",
    "read_water",
    "real_path",
    "undo_profile",
    "write_profile",
]
