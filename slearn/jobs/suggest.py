"""A spec that learns the right task as written, suggested from log profiles.

:func:`suggest_spec` reads what :func:`slearn.jobs.info.describe_log` measured and writes a
TOML spec whose uncommented entries learn as they are:

- **Roles** from topic names and types: a topic whose name has ``cmd``, ``command``,
  ``setpoint``, ``goal`` or ``target``, a channel whose metadata says ``role = action``
  (slearn's recorders), and command types (``Twist``, ``JointTrajectory``,
  ``Float64MultiArray``, ...) are actions; everything else is an observation.
- **Skipped fields**: time stamps, sequence numbers, frame ids, joint names, constants and
  free text, each listed in a comment with the reason.
- **Symbols**: integers, strings and booleans with few values are categorical (the
  values seen are declared). Numbers on a regular grid (a quantized sensor: a pointer
  read in 10 degree steps) get one bin per grid value, and wrap when the grid covers a
  full turn. Other numbers get ``count`` equal bins over the range seen in the data.
- **Mode**: ``message`` (every message is an event: repeated commands and unchanged
  readings are part of the task), with the reason in a comment.
- **Which entries are live**: every action field, and the best observation candidates
  (joint positions first, then other positions, then the fields that vary most); the
  other candidates are written commented out, ready to uncomment.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from typing import Iterable

from slearn.errors import DataWarning
from slearn.jobs.info import ChannelProfile, FieldInfo, LogProfile

OBSERVATIONS_LIVE = 3  # observation fields uncommented
CATEGORICAL_MAX = 64  # distinct values up to which integers and strings are categorical
GRID_MAX = 64  # grid points up to which a quantized number gets one bin per value
CONTINUOUS_BINS = 10
TURN = 2 * math.pi

_ACTION_WORDS = re.compile(r"(^|[/_.\-])(cmd|cmds|cmd_vel|command|commands|setpoint|setpoints|goal|"
                           r"goals|target|targets)($|[/_.\-])", re.I)
_ACTION_TYPES = ("Twist", "TwistStamped", "JointTrajectory", "MultiDOFJointTrajectory",
                 "Float64MultiArray", "AckermannDrive", "AckermannDriveStamped", "JointJog")
_SKIP = [(re.compile(r"(^|\.)stamp(\.|$)|(^|\.)(sec|secs|nsec|nsecs|nanosec)$"), "time stamps"),
         (re.compile(r"(^|\.)seq$"), "sequence numbers"),
         (re.compile(r"frame_id$"), "frame ids"),
         (re.compile(r"(^|\.)name\[|(^|\.)joint_names\[|^layout\."), "names and layouts")]


@dataclass
class Candidate:
    """A field that could be an entry: where, its role, its symbolizer lines and why."""

    channel: ChannelProfile
    info: FieldInfo
    role: str
    keys: list[str]
    why: str
    rank: tuple = ()


@dataclass
class _Block:
    """One channel's part of the spec: its head, reasons, skipped fields and candidates."""

    channel: ChannelProfile
    role: str
    role_why: str
    skipped: dict[str, list[str]] = field(default_factory=dict)
    candidates: list[Candidate] = field(default_factory=list)


def guess_role(channel: ChannelProfile) -> tuple[str, str]:
    """``(role, reason)`` from the channel's metadata, topic name and type."""
    declared = channel.metadata.get("role")
    if declared in ("action", "observation"):
        return declared, f"the channel's metadata says role = {declared}"
    match = _ACTION_WORDS.search(channel.topic)
    if match:
        return "action", f"the topic name has {match.group(2)!r}: a command"
    type_name = channel.schema.rsplit("/", 1)[-1]
    if type_name in _ACTION_TYPES:
        return "action", f"{channel.schema} is a command type"
    return "observation", "not a command by name or type"


def _skip_reason(info: FieldInfo) -> str | None:
    for pattern, reason in _SKIP:
        if pattern.search(info.path):
            return reason
    if info.count == 0:
        return "never present"
    if info.constant:
        return "constant"
    if info.type == "str" and info.n_distinct is None:
        return "free text (many distinct values)"
    return None


def _grid(values: list[float]) -> float | None:
    """The step of a regular grid holding every value (``None`` if they are not on one)."""
    values = sorted(values)
    step = min(b - a for a, b in zip(values, values[1:]))
    if step <= 0 or (values[-1] - values[0]) / step > GRID_MAX:
        return None
    if step < 1e-3 * max(abs(values[0]), abs(values[-1]), 1.0):
        return None  # encoder ticks of a joint that barely moves: no grid worth a bin each
    ok = all(abs((v - values[0]) / step - round((v - values[0]) / step)) < 1e-3 for v in values)
    return step if ok else None


def _number_keys(info: FieldInfo) -> tuple[list[str], str]:
    lo, hi = float(info.min or 0.0), float(info.max or 0.0)  # numeric fields always have both
    step = _grid(info.distinct) if info.n_distinct is not None and len(info.distinct) > 1 else None
    if step is not None:
        count = round((hi - lo) / step) + 1
        low, high = lo - step / 2, hi + step / 2
        if abs(count * step - TURN) < 0.01 * TURN:
            return ([f"range = [{_num(low)}, {_num(low + TURN)}]", f"count = {count}", "wrap = true",
                     'unit = "rad"'],
                    f"{info.n_distinct} values on a grid of {math.degrees(step):g} degrees covering "
                    f"the full turn: one bin per value, wrapping")
        if _is_angle(info) and abs(count * step - 360.0) < 0.01 * 360.0:  # an angle in degrees
            return ([f"range = [{_num(low)}, {_num(low + 360.0)}]", f"count = {count}", "wrap = true",
                     'unit = "deg"'],
                    f"{info.n_distinct} values on a grid of {step:g} degrees covering the full turn: "
                    f"one bin per value, wrapping")
        return ([f"range = [{_num(low)}, {_num(high)}]", f"count = {count}"],
                f"{info.n_distinct} values on a grid of step {step:g}: one bin per value")
    if _is_angle(info) and _in_degrees(info, hi - lo):
        if hi - lo > 0.9 * 360.0:
            low = 0.0 if lo >= -0.05 * 180.0 else -180.0
            return ([f"range = [{_num(low)}, {_num(low + 360.0)}]", "count = 36", "wrap = true", 'unit = "deg"'],
                    "an angle in degrees covering the full turn: 36 bins of 10 degrees, wrapping")
    elif _is_angle(info) and hi - lo > 0.9 * TURN:  # radians; more than a turn wraps onto it
        low = 0.0 if lo >= -0.05 else -math.pi
        return ([f"range = [{_num(low)}, {_num(low + TURN)}]", "count = 36", "wrap = true", 'unit = "rad"'],
                "an angle covering the full turn: 36 bins of 10 degrees, wrapping")
    return ([f"range = [{_num(lo)}, {_num(hi)}]", f"count = {CONTINUOUS_BINS}"],
            f"{CONTINUOUS_BINS} equal bins over the range seen ({info.min:.6g} .. {info.max:.6g}); "
            f"values outside it are counted and warned about")


def _in_degrees(info: FieldInfo, span: float) -> bool:
    """Whether an angle is in degrees: its name says ``deg``, or, unless it says ``rad``,
    its values span about one turn of degrees (360; in radians that is some fifty turns)."""
    name = info.path.rsplit(".", 1)[-1].lower()
    if re.search(r"rad", name):
        return False
    return bool(re.search(r"deg", name)) or 0.9 * 360.0 < span <= 1.01 * 360.0


def _is_angle(info: FieldInfo) -> bool:
    return bool(re.search(r"(^|\.)(position\[|angle|yaw|heading|theta)", info.path))


def _num(x: float) -> str:
    return repr(0.0 if abs(x) < 1e-9 else x)  # a grid starting at 0 comes out as 1e-17


def _symbolizer(info: FieldInfo) -> tuple[list[str], str]:
    few = info.n_distinct is not None and info.n_distinct <= CATEGORICAL_MAX
    if info.type in ("str", "bool") or (info.type == "int" and few):
        if not few:
            return [], ""
        values = ", ".join(_toml_value(v) for v in sorted(info.distinct, key=_sort_key))
        return [f"values = [{values}]"], f"{info.n_distinct} distinct values: categorical"
    if info.type in ("int", "float") and info.min is not None:
        return _number_keys(info)
    return [], ""


def _sort_key(value) -> tuple:
    return (0, value, "") if isinstance(value, (int, float)) else (1, 0, str(value))


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    return _toml_str(str(value))


def _toml_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _rank(candidate: Candidate) -> tuple:
    """Lower is better: joint positions, other positions, then the fields that vary most."""
    path, schema = candidate.info.path, candidate.channel.schema
    group = 0 if path.startswith("position[") and schema.endswith("JointState") else \
        1 if re.search(r"(^|\.)(position|pos|angle|data)\b", path) else 2
    info = candidate.info
    spread = (info.max - info.min) if info.min is not None and info.max is not None else 0.0
    return group, -info.changes / max(info.count, 1), -spread, candidate.channel.topic, path


def _block(channel: ChannelProfile) -> _Block:
    role, why = guess_role(channel)
    block = _Block(channel, role, why)
    for info in channel.fields:
        reason = _skip_reason(info)
        keys, because = ([], "") if reason else _symbolizer(info)
        if reason or not keys:
            block.skipped.setdefault(reason or "no usable values", []).append(info.path)
            continue
        candidate = Candidate(channel, info, role, keys, because)
        candidate.rank = _rank(candidate)
        block.candidates.append(candidate)
    return block


def _merged_channels(profiles: list[LogProfile]) -> list[ChannelProfile]:
    """One profile per (topic, schema): the first log's, its fields widened by the others'."""
    merged: dict[tuple[str, str], ChannelProfile] = {}
    for profile in profiles:
        for channel in profile.channels:
            key = (channel.topic, channel.schema)
            if key not in merged:
                merged[key] = channel
            else:
                _widen(merged[key], channel)
    return list(merged.values())


def _widen(into: ChannelProfile, other: ChannelProfile) -> None:
    known = {f.path: f for f in into.fields}
    into.count += other.count
    for info in other.fields:
        mine = known.get(info.path)
        if mine is None:
            continue
        if info.min is not None and info.max is not None:
            mine.min = info.min if mine.min is None else min(mine.min, info.min)
            mine.max = info.max if mine.max is None else max(mine.max, info.max)
        mine.count, mine.changes = mine.count + info.count, mine.changes + info.changes
        for value in info.distinct:
            if value not in mine.distinct:
                mine.distinct.append(value)
        mine.more_distinct = (mine.more_distinct or info.more_distinct
                              or len(mine.distinct) > CATEGORICAL_MAX)


def suggest_spec(profiles: Iterable[LogProfile]) -> str:
    """A TOML spec for the logs; its uncommented entries learn as written (see the module doc)."""
    profiles = list(profiles)
    blocks = [_block(c) for c in _merged_channels(profiles) if c.count and not c.decode_error]
    actions = [c for b in blocks for c in b.candidates if c.role == "action"]
    observations = sorted((c for b in blocks for c in b.candidates if c.role == "observation"),
                          key=lambda c: c.rank)
    live = {id(c) for c in actions + observations[:OBSERVATIONS_LIVE]}
    lines = _header(profiles, actions, observations)
    for block in blocks:
        lines += _block_lines(block, live)
    undecodable = [c for p in profiles for c in p.channels if c.decode_error]
    lines += [f"# --- {c.topic}: cannot be decoded: {c.decode_error}" for c in undecodable]
    return "\n".join(lines).rstrip() + "\n"


def _header(profiles: list[LogProfile], actions: list, observations: list) -> list[str]:
    lines = ["# slearn spec suggested by `slearn info --suggest-spec` from:"]
    lines += [f"#   {p.path}" for p in profiles]
    if observations:
        lines += ["#",
                  "# It learns as written. The uncommented entries are every command field and the",
                  f"# {OBSERVATIONS_LIVE} best observation candidates; uncomment others to add them "
                  "(each observation",
                  "# channel makes every step's observation finer, so more must be seen to learn it)."]
    else:
        lines += ["#",
                  "# It has no observation entry, so it learns nothing as written: no field of",
                  "# these logs has values slearn can predict (each topic below says why its fields",
                  "# were skipped). Add one (README: From your own logs) before `slearn learn`."]
    lines += ["#",
              "# mode \"message\": every message of an entry is an event, so a step is a command and",
              "# the readings that follow it; repeated commands and unchanged readings are part of",
              "# the task. (\"change\" keeps only changes and predicts a different, easier-looking",
              "# task; give it per entry with mode = \"change\" only if that is the question.)",
              'mode = "message"', ""]
    if not actions:
        lines[-1:-1] = ["# No command topic was found, so every entry is an observation: the library",
                        "# learns what the sensors do next by themselves. If a topic carries commands,",
                        "# set its role = \"action\".", ""]
    if not observations:
        lines += ["# No observation field with usable values was found.", ""]
    return lines


def _block_lines(block: _Block, live: set[int]) -> list[str]:
    c = block.channel
    rate = f"{c.rate_hz:.1f} Hz" if c.rate_hz else "rate n/a"
    lines = [f"# --- {c.topic}  ({c.schema or 'schemaless'}, {c.message_encoding}, "
             f"{c.count:,} messages, {rate})", f"# {block.role}: {block.role_why}"]
    for reason, paths in block.skipped.items():
        shown = ", ".join(paths[:6]) + (f", ... ({len(paths)} fields)" if len(paths) > 6 else "")
        lines.append(f"# skipped ({reason}): {shown}")
    for candidate in sorted(block.candidates, key=lambda x: (id(x) not in live, x.rank)):
        lines += _entry_lines(candidate, id(candidate) in live)
    return lines + [""]


def _entry_lines(candidate: Candidate, live: bool) -> list[str]:
    info = candidate.info
    examples = ", ".join(f"{v:.6g}" if isinstance(v, float) else repr(v) for v in info.examples[:5])
    entry = ["[[channel]]", f"topic = {_toml_str(candidate.channel.topic)}",
             f"field = {_toml_str(info.path)}", f'role = "{candidate.role}"', *candidate.keys]
    note = [f"# {info.path}: {candidate.why}; e.g. {examples}"]
    return note + (entry if live else [f"# {line}" for line in entry])


def with_action_scopes(text: str, paths: Iterable[str], window=None) -> str:
    """``text`` (a suggested spec) with ``actions = [...]`` on each live observation entry
    that recorded steps show to depend on only some of the action entries
    (:func:`slearn.core.action_scopes.suggest_scopes`, on the first steps of ``paths``).
    A spec with fewer than two action entries is returned as it is."""
    import tomllib

    from slearn.errors import SpecError
    from slearn.io.spec import _build_spec

    try:
        spec = _build_spec(tomllib.loads(text), "<suggested>")
    except SpecError:  # no entry at all: nothing to scope (the caller says what is missing)
        return text
    if sum(c.role == "action" for c in spec.channels) < 2 or not spec.fitted \
            or not any(c.role == "observation" for c in spec.channels):
        return text
    from slearn.core.action_scopes import MAX_STEPS, suggest_scopes  # (reading compiles kernels)
    from slearn.core.vocabulary import Vocabulary
    from slearn.io.serialize import read_pieces

    vocabulary, kept, steps = Vocabulary(), [], 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the log's warnings come with learning, not here
        for _, piece, *_ in read_pieces(list(paths), spec, vocabulary, False, window):
            kept.append(piece)
            steps += len(piece)
            if steps >= MAX_STEPS:
                break
    scopes = suggest_scopes(kept, vocabulary)
    if not scopes:
        return text
    lines, out, entry = text.split("\n"), [], -1
    for line in lines:
        out.append(line)
        if line == "[[channel]]":
            entry += 1
        elif entry >= 0 and line.startswith("role = ") and spec.channels[entry].name in scopes:
            names = scopes[spec.channels[entry].name]
            out.append(f"actions = [{', '.join(_toml_str(n) for n in names)}]  # its own command"
                       f"{'s' if len(names) > 1 else ''}: the readings depend on "
                       f"{'these' if len(names) > 1 else 'this'} alone (code length on the first steps)"
                       if names else "actions = []  # no command changes these readings "
                       "(code length on the first steps)")
    return "\n".join(out)


def suggested_text(profiles: list[LogProfile], window=None) -> str:
    """The TOML spec ``slearn info --suggest-spec`` writes for profiled logs: the suggestion,
    with the action scopes their first steps (in ``window``) show."""
    return with_action_scopes(suggest_spec(profiles), [p.path for p in profiles], window)


def suggested_spec(paths: Iterable[str], window=None):
    """The spec ``slearn info --suggest-spec`` writes for ``paths`` (profiled and scoped on
    ``window`` of each, the part that is learned), parsed: what ``learn --spec auto`` learns.

    Raises:
        SpecError: no field of the logs can be an entry.
        InputError: a log cannot be read.
    """
    import tomllib

    from slearn.errors import SpecError
    from slearn.io.spec import Spec
    from slearn.jobs.info import describe_log

    paths = list(paths)
    text = suggested_text([describe_log(p, window=window) for p in paths], window)
    try:
        return Spec.from_dict(tomllib.loads(text), "--spec auto")
    except SpecError as err:
        raise SpecError(f"{err} (`slearn info {paths[0]}` shows every field; write a spec with "
                        "--spec FILE)") from err


HINT_STEPS = 20_000
"""Steps of a learn job that :class:`ScopeHint` looks at (the first ones)."""


class ScopeHint:
    """Watches the first steps a learn job reads; when the spec has two or more action
    entries and no ``actions`` scopes, the steps combine commands (more distinct command
    tuples than values of the commands one at a time: several change together), and they
    show observations driven by some commands only
    (:func:`slearn.core.action_scopes.suggest_scopes`), :meth:`warn` says so:
    without scopes each observation's contexts hold the whole command tuple, which rarely
    repeats when many commands change at once (a 7-joint arm: 0.30 per joint against 1.00)."""

    def __init__(self, spec, vocabulary, library) -> None:
        self.vocabulary, self.steps = vocabulary, 0
        self.pieces: list = []  # the first steps' episodes (pieces)
        # (a library's scopes are its spec's; a literal library has none to give)
        self.active = (sum(c.role == "action" for c in spec.channels) >= 2
                       and getattr(library, "action_scopes", None) == {})

    def see(self, piece) -> None:
        """Keep ``piece`` (a learned one) if the first steps are not all seen yet."""
        if self.active:
            self.pieces.append(piece)
            self.steps += len(piece)
            if self.steps >= HINT_STEPS:
                self.warn()

    def warn(self) -> None:
        """Say it, at most once (at the latest when learning ends)."""
        if not self.active or not self.pieces:
            return
        self.active = False
        from slearn.core.action_scopes import suggest_scopes  # (`info` imports this module)

        pieces, self.pieces = self.pieces, []
        if not _combined_commands(pieces):
            return
        scopes = suggest_scopes(pieces, self.vocabulary, HINT_STEPS)
        if scopes:
            view, names = next(iter(scopes.items()))
            warnings.warn(DataWarning(
                f"{len(scopes)} observation channel(s) depend on some commands only in the first "
                f"{min(self.steps, HINT_STEPS):,} steps (e.g. {view}: {', '.join(names) or 'none'}), "
                f"but the spec gives no `actions` scopes, so each is predicted from the whole command "
                f"tuple: `slearn info LOG --suggest-spec spec.toml` writes them"), stacklevel=3)


def _combined_commands(pieces) -> bool:
    """Whether the steps of ``pieces`` hold more distinct command tuples than distinct
    command values (one command per step, as a pointer arm sends them, gives as many)."""
    tuples: set[tuple] = set()
    values: set[int] = set()
    for piece in pieces:
        offsets, n_actions, symbols = piece.step_offsets.tolist(), piece.n_actions.tolist(), piece.symbols
        for s, n in enumerate(n_actions):
            if n:  # (a step without commands is no combination)
                step = tuple(symbols[offsets[s]:offsets[s] + n].tolist())
                tuples.add(step)
                values.update(step)
    return len(tuples) > len(values)
