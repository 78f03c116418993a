"""The channel spec: which topics and fields become events, their roles, and their symbols.

A spec is a TOML file::

    mode = "message"       # default: every message of an entry is an event
                           # "change": an event only when the entry's symbol changes
                           # "tick": a fixed-rate tick with sample-and-hold (set tick_ms)
    # tick_ms = 100        # or tick_ns = 100_000_000
    # phase_ms = 50        # tick mode: sample the observations this long after the
                           # commands of each tick (0 < phase <= tick; default: one tick)

    [[channel]]
    topic = "/joint_states"
    field = "position[name=r_shoulder_pan_joint]"
    role = "observation"   # or "action"
    name = "r_shoulder_pan"  # optional; default: the topic, or "topic:field" when a
                             # topic has several entries
    range = [-2.0, 2.0]    # numeric: `count` uniform bins over the range (values
    count = 8              # outside fall in the end bins and are counted and warned
    # clip = true          # about, unless clip = true accepts them silently)
    # wrap = true          # angles: values wrap into the range before binning
    # unit = "rad"         # how bins are labelled: "rad" and "deg" show degrees
    # mode = "change"      # this entry only: an event when its symbol changes
    # actions = ["/pointer/command"]  # observations only: predicted from these actions alone

    [[channel]]
    topic = "/pointer/command"
    field = "command"
    role = "action"
    values = ["L", "R"]    # categorical with declared values (fixes symbol order)

Limits (refused with a one-line error naming the entry and the key): at most
:data:`MAX_SYMBOLS` (10^6) symbols per channel (``count``, ``quantiles``, ``edges``,
``values``, and the values a log brings) unless the entry raises it with ``max_symbols =
N`` (up to 2^31 - 1); ``tick_ms`` from 0.000001 (1 ns) to 86,400,000 (a day); ``width`` and
``origin``, ``range`` and ``edges`` finite (``width`` from 1e-300 to 1e300, ``range`` low
< high with a finite span, ``edges`` strictly increasing); ``values`` distinct strings,
integers, finite numbers or booleans; at most :data:`MAX_CHANNELS` entries.

Symbolizers (one per entry; no binning key means categorical, values as they are):
``values = [...]`` (categorical, declared order first), ``width`` + ``origin`` (uniform
bins, unbounded, the symbol is ``floor((x - origin) / width)``), ``range`` + ``count``
(optionally ``wrap``, ``clip``), ``edges = [...]`` (bin ``k`` holds
``edges[k-1] <= x < edges[k]``), ``quantiles = n`` (``n`` bins with edges fitted on
training logs, see :func:`slearn.io.serialize.fit_spec`). Bin symbols are bin indices
(``int``); :meth:`Spec.value_label` shows them as value ranges (``[50°, 60°)``).

Action scopes: an observation entry's ``actions = [names]`` (entry names of action entries)
makes its channel see the step's actions on those channels only (a joint's own command; see
:mod:`slearn.core.views`): a robot commanding many joints at once gives command tuples that
rarely repeat, while each joint's own (command, reading) pairs do. Without it an
observation sees every action.

Modes: the file's ``mode`` is the default of every entry; an entry's own ``mode``
(``"message"`` or ``"change"``) overrides it. ``"tick"`` is for the whole file only.

The CLI shorthand ``TOPIC:FIELD:ROLE[:OPTIONS]`` (:func:`parse_channel_option`) makes
one entry; OPTIONS are ``key=value`` pairs separated by commas; a list is written in
brackets, ``[a,b]`` (or its items separated by ``;``):
``/joint_states:position[name=r_wrist_roll_joint]:observation:range=[-3,3],count=6``.

:meth:`Spec.to_dict` / :meth:`Spec.from_dict` give plain JSON-able data, fitted edges
included, so a saved library re-bins held-out logs identically.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import tomllib
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Hashable, Iterable

from slearn.core.vocabulary import ACTION, OBSERVATION, ROLES
from slearn.errors import FieldPathError, SpecError
from slearn.io.decode import FieldPath, parse_field_path, split_outside_brackets

MODES = ("message", "change", "tick")
CHANNEL_MODES = ("message", "change")
DEFAULT_MODE = "message"

_BIN_KEYS = ("width", "origin", "range", "count", "edges", "quantiles", "wrap", "clip", "unit")
_ENTRY_KEYS = ("topic", "field", "role", "name", "values", "mode", "max_symbols", "actions") + _BIN_KEYS
_SPEC_KEYS = ("mode", "tick_ms", "tick_ns", "phase_ms", "phase_ns", "channel")
_DEGREE_UNITS = {"rad": 180.0 / math.pi, "deg": 1.0}

MAX_SYMBOLS = 1_000_000        # symbols per channel unless an entry raises it (max_symbols)
MAX_SYMBOLS_LIMIT = (1 << 31) - 1  # symbols are int32
MAX_CHANNELS = 10_000
TICK_NS_RANGE = (1, 86_400 * 1_000_000_000)  # 1 ns to a day
WIDTH_RANGE = (1e-300, 1e300)
MAX_ORIGIN = 1e300
_MAX_BIN_INDEX = 1 << 53  # beyond it a bin index is not exact in a float: the value is skipped


@dataclass(frozen=True)
class Categorical:
    """Values as they are; ``values`` (optional) are registered first, in this order."""

    values: tuple | None = None

    def symbol_value(self, x: Any) -> Hashable | None:
        """The vocabulary value of a field value (lists become tuples)."""
        if isinstance(x, (list, tuple)):
            return tuple(x)
        if isinstance(x, (bytes, bytearray)) or x is None:
            return None
        if isinstance(x, float) and math.isnan(x):
            return None  # NaN never equals itself: every reading would be a new symbol
        return x

    def declared_values(self) -> list | None:
        """Values to register up front, in order."""
        return list(self.values) if self.values is not None else None

    @property
    def fitted(self) -> bool:
        """Categorical symbolizers need no fitting."""
        return True

    def to_dict(self) -> dict:
        """Plain JSON-able description."""
        return {"values": list(self.values)} if self.values is not None else {}


@dataclass(frozen=True)
class Bins:
    """Numeric bins; exactly one of ``width``, ``range``/``count``, ``edges``, ``quantiles``."""

    width: float | None = None
    origin: float = 0.0
    range: tuple[float, float] | None = None
    count: int | None = None
    edges: tuple[float, ...] | None = None
    quantiles: int | None = None
    wrap: bool = False
    clip: bool = False
    unit: str | None = None
    _cuts: tuple[float, ...] = dataclasses.field(default=(), init=False, repr=False, compare=False)  # cuts()

    @property
    def fitted(self) -> bool:
        """False for quantile bins whose edges are not fitted yet."""
        return self.quantiles is None or self.edges is not None

    def cuts(self) -> tuple[float, ...]:
        """Bin boundaries for bisection (not used by ``width`` bins)."""
        if self.range is not None and self.quantiles is None:
            lo, hi = self.range
            count = self.count or 1  # validated: range bins always have a count
            return tuple(lo + (hi - lo) * k / count for k in range(1, count))
        return self.edges or ()

    def n_bins(self) -> int | None:
        """Number of bins, ``None`` when unbounded (``width``)."""
        return None if self.width is not None else len(self.cuts()) + 1

    def symbol_value(self, x: Any) -> int | None:
        """The bin index of ``x``; ``None`` for non-numbers, NaN, infinities, integers too
        large for a float, and ``width`` bins beyond +-2^53."""
        try:
            x = float(x)
        except (TypeError, ValueError, OverflowError):
            return None
        if not math.isfinite(x):
            return None
        if self.wrap and self.range is not None:
            lo, hi = self.range
            x = lo + (x - lo) % (hi - lo)
        if self.width is not None:
            q = (x - self.origin) / self.width
            return math.floor(q) if abs(q) < _MAX_BIN_INDEX else None
        return bisect.bisect_right(self._cuts, x)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_cuts", self.cuts() if self.width is None else ())

    def declared_values(self) -> list | None:
        """Bounded bins register all bin indices up front."""
        n = self.n_bins()
        return list(range(n)) if n is not None and self.fitted else None

    def outside(self, x: Any) -> bool:
        """Whether ``x`` falls outside ``range`` and would be binned into an end bin.

        Only ``range`` bins (not wrapped) have bounds; ``clip = true`` accepts such values.
        """
        if self.range is None or self.quantiles is not None or self.wrap or self.clip:
            return False
        try:
            x = float(x)
        except (TypeError, ValueError, OverflowError):
            return False  # not binned at all (see symbol_value)
        return math.isfinite(x) and (x < self.range[0] or x > self.range[1])

    def bounds(self, k: int) -> tuple[float, float]:
        """The values bin ``k`` stands for, ``(low, high)``; infinite for open end bins."""
        if self.width is not None:
            a = self.origin + k * self.width
            return a, a + self.width
        cuts = self.cuts()
        ends = self.range if self.range is not None and self.quantiles is None else (-math.inf, math.inf)
        return (cuts[k - 1] if k > 0 else ends[0]), (cuts[k] if k < len(cuts) else ends[1])

    def label(self, k: int) -> str:
        """``[a, b)`` text of bin ``k``, in degrees for angles (``unit = "rad"`` or ``"deg"``)."""
        a, b = self.bounds(k)
        scale = _DEGREE_UNITS.get(self.unit or "", 1.0)
        width = (b - a) * scale if math.isfinite(b - a) else None
        text = f"[{_number_text(a * scale, width)}, {_number_text(b * scale, width)})"
        if self.unit in _DEGREE_UNITS:
            return text.replace(",", "°,").replace(")", "°)").replace("inf°", "inf")
        return f"{text} {self.unit}" if self.unit else text

    def to_dict(self) -> dict:
        """Plain JSON-able description, fitted edges included."""
        out: dict[str, Any] = {}
        if self.width is not None:
            out.update(width=self.width, origin=self.origin)
        if self.range is not None:
            out.update(range=list(self.range), count=self.count)
        if self.quantiles is not None:
            out["quantiles"] = self.quantiles
        if self.edges is not None:
            out["edges"] = list(self.edges)
        if self.wrap:
            out["wrap"] = True
        if self.clip:
            out["clip"] = True
        if self.unit:
            out["unit"] = self.unit
        return out


def _number_text(x: float, width: float | None) -> str:
    """``x`` with as many decimals as a bin ``width`` needs (2 significant digits of it)."""
    if not math.isfinite(x):
        return "inf" if x > 0 else "-inf"
    decimals = max(0, 1 - math.floor(math.log10(width))) if width else 6
    text = f"{x:.{decimals}f}"
    text = text.rstrip("0").rstrip(".") if "." in text else text
    return "0" if text in ("-0", "") else text


Symbolizer = Categorical | Bins


@dataclass(frozen=True)
class ChannelSpec:
    """One entry: a field of a topic, its role, its vocabulary channel name, its symbolizer."""

    topic: str
    field: str
    role: str
    name: str
    symbolizer: Symbolizer = dataclasses.field(default_factory=Categorical)
    max_symbols: int | None = None
    mode: str | None = None
    actions: tuple[str, ...] | None = None  # an observation's action scope (entry names)

    @property
    def path(self) -> FieldPath:
        """The parsed field path."""
        return parse_field_path(self.field)

    @property
    def symbol_limit(self) -> int:
        """Most symbols this entry's channel may have (:data:`MAX_SYMBOLS` unless raised)."""
        return self.max_symbols or MAX_SYMBOLS

    def to_dict(self) -> dict:
        """Plain JSON-able description."""
        limit = {"max_symbols": self.max_symbols} if self.max_symbols is not None else {}
        out = {"topic": self.topic, "field": self.field, "role": self.role,
               "name": self.name, **limit, **self.symbolizer.to_dict()}
        if self.mode is not None:
            out["mode"] = self.mode
        if self.actions is not None:
            out["actions"] = list(self.actions)
        return out

    def value_label(self, value: Any) -> str:
        """How a symbol value of this entry reads: bins as value ranges, others as they are."""
        if isinstance(self.symbolizer, Bins) and isinstance(value, int) and not isinstance(value, bool):
            return self.symbolizer.label(value)
        return str(value)


@dataclass(frozen=True)
class Spec:
    """A channel spec: entries in order, the serialization mode and the tick period."""

    channels: tuple[ChannelSpec, ...]
    mode: str = DEFAULT_MODE
    tick_ns: int | None = None
    source: str = "<spec>"
    phase_ns: int | None = None

    def topics(self) -> list[str]:
        """Topics the spec reads, in spec order, without repeats."""
        return list(dict.fromkeys(c.topic for c in self.channels))

    def action_scopes(self) -> dict[str, tuple[str, ...]]:
        """``{observation channel: its action channels}`` of the entries that name them."""
        return {c.name: c.actions for c in self.channels if c.actions is not None}

    def channel_mode(self, index: int) -> str:
        """The event mode of entry ``index``: its own, else the file's."""
        return self.channels[index].mode or self.mode

    def value_label(self, name: str, value: Any) -> str:
        """``value`` of the entry named ``name`` as text (bins as value ranges)."""
        for entry in self.channels:
            if entry.name == name:
                return entry.value_label(value)
        return str(value)

    def only_topics(self, topics: Iterable[str]) -> "Spec":
        """A copy with only the entries of ``topics``.

        Raises:
            SpecError: a topic is not in the spec, or no entry would remain.
        """
        wanted = list(dict.fromkeys(topics))
        unknown = [t for t in wanted if t not in self.topics()]
        if unknown:
            raise SpecError(f"{self.source}: --topics {unknown[0]!r} is not a topic of the spec "
                            f"(topics: {', '.join(self.topics())})")
        return self.with_channels(c for c in self.channels if c.topic in wanted)

    def warnings(self) -> list[str]:
        """What about this spec could make a score mean something else than it seems."""
        if any(c.role == ACTION for c in self.channels):
            return []
        return [f"{self.source}: the spec has no action channel, so every entry is predicted "
                f"from the others' history alone; if a topic carries commands (cmd, setpoint, "
                f"goal), give it role = \"action\""]

    def predicting(self) -> "Spec":
        """This spec, for learning: it must have an observation entry (actions are given and
        observations predicted, so a library of actions alone would stay empty).

        Raises:
            SpecError: no entry has the observation role.
        """
        if not any(c.role == OBSERVATION for c in self.channels):
            raise SpecError(f"{self.source}: no observation entry, so nothing to predict (actions are "
                            f"given, observations predicted): give an entry role = \"observation\"")
        return self

    @property
    def fitted(self) -> bool:
        """True when every symbolizer is ready (quantile edges fitted)."""
        return all(c.symbolizer.fitted for c in self.channels)

    def to_dict(self) -> dict:
        """Plain JSON-able data (fitted edges included); :meth:`from_dict` reads it back."""
        out: dict[str, Any] = {"mode": self.mode, "channel": [c.to_dict() for c in self.channels]}
        if self.tick_ns is not None:
            out["tick_ns"] = self.tick_ns
        if self.phase_ns is not None:
            out["phase_ns"] = self.phase_ns
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "<spec>") -> "Spec":
        """Build and check a spec from plain data (a parsed TOML file or :meth:`to_dict`)."""
        return _build_spec(data, source)

    def with_channels(self, channels: Iterable[ChannelSpec]) -> "Spec":
        """A copy with other entries."""
        return replace(self, channels=tuple(channels))


def value_labels(spec: Spec) -> dict[str, Any]:
    """Per binned entry name, the function that shows its bins as value ranges."""
    return {c.name: c.value_label for c in spec.channels if isinstance(c.symbolizer, Bins)}


def load_spec(path: str | Path) -> Spec:
    """Read a TOML spec file.

    Raises:
        SpecError: the file cannot be read, is not TOML, or an entry is invalid; the
            message names the file, the entry and the field.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise SpecError(f"{path}: cannot read spec: {err.strerror or err}") from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise SpecError(f"{path}: not valid TOML: {err}") from err
    return _build_spec(data, str(path))


def _build_spec(data: dict, source: str) -> Spec:
    if not isinstance(data, dict):
        raise SpecError(f"{source}: a spec is a table of keys")
    unknown = sorted(set(data) - set(_SPEC_KEYS))
    if unknown:
        raise SpecError(f"{source}: unknown key(s) {', '.join(unknown)} (known: {', '.join(_SPEC_KEYS)})")
    mode = data.get("mode", DEFAULT_MODE)
    if mode not in MODES:
        raise SpecError(f"{source}: mode must be one of {', '.join(MODES)}, not {mode!r}")
    tick_ns = _tick_ns(data, mode, source)
    phase_ns = _phase_ns(data, mode, tick_ns, source)
    entries = data.get("channel")
    if not isinstance(entries, list) or not entries:
        raise SpecError(f"{source}: no [[channel]] entries: a spec needs at least one")
    if len(entries) > MAX_CHANNELS:
        raise SpecError(f"{source}: {len(entries)} [[channel]] entries; at most {MAX_CHANNELS:,}")
    topics = Counter(e["topic"] for e in entries
                     if isinstance(e, dict) and isinstance(e.get("topic"), str))
    channels = tuple(_build_entry(e, i, topics, source) for i, e in enumerate(entries))
    name, n = Counter(c.name for c in channels).most_common(1)[0]
    if n > 1:
        raise SpecError(f"{source}: two entries are named {name!r}: give them distinct `name`s")
    roles = {c.name: c.role for c in channels}
    known = ", ".join(n for n, r in roles.items() if r == ACTION) or "none"
    for i, c in enumerate(channels):
        for action in c.actions or ():
            if roles.get(action) != ACTION:
                raise SpecError(f"{_where(source, i, entries[i])}: `actions` names {action!r}, which is "
                                f"{'an observation entry' if action in roles else 'no entry'}: give "
                                f"the names of action entries ({known})")
    if mode == "tick" and any(c.mode for c in channels):
        raise SpecError(f"{source}: mode \"tick\" samples every entry at each tick: drop the "
                        f"entries' own `mode`")
    return Spec(channels, mode, tick_ns, source, phase_ns)


def _phase_ns(data: dict, mode: str, tick_ns: int | None, source: str) -> int | None:
    if mode != "tick" and ("phase_ms" in data or "phase_ns" in data):
        raise SpecError(f"{source}: phase_ms is for mode \"tick\" (the sampling instant after "
                        f"each tick's commands)")
    if mode != "tick" or tick_ns is None:
        return None
    return _duration_ns(data, "phase", (1, tick_ns), "after the tick's commands: above 0, at "
                        "most one tick", source)


def _tick_ns(data: dict, mode: str, source: str) -> int | None:
    tick = _duration_ns(data, "tick", TICK_NS_RANGE, "1 ns to a day", source)
    if tick is None and mode == "tick":
        raise SpecError(f"{source}: mode \"tick\" needs tick_ms (or tick_ns)")
    if tick is not None and mode != "tick":
        raise SpecError(f"{source}: tick_ms is for mode \"tick\" (every entry sampled at each tick); "
                        f"mode {mode!r} would ignore it: set mode = \"tick\" or drop it")
    return tick


def _duration_ns(data: dict, name: str, bounds: tuple[int, int], what: str,
                 source: str) -> int | None:
    """``NAME_ms`` or ``NAME_ns`` of the file in ns, ``None`` when neither is given."""
    ms, ns = f"{name}_ms", f"{name}_ns"
    if ms in data and ns in data:
        raise SpecError(f"{source}: give {ms} or {ns}, not both")
    key = ms if ms in data else ns if ns in data else None
    if key is None:
        return None
    value, scale = data[key], 1_000_000 if key == ms else 1
    lo, hi = bounds
    if not _is_number(value) or not lo <= value * scale <= hi:
        raise SpecError(f"{source}: `{key}` must be a number from {lo / scale:g} to {hi / scale:g}"
                        f" ({what}), not {_shown(value)}")
    return int(value * scale)


def _is_number(value: Any) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _where(source: str, i: int, entry: dict) -> str:
    topic = entry.get("topic", "?") if isinstance(entry, dict) else "?"
    fld = entry.get("field", "") if isinstance(entry, dict) else ""
    return f"{source}: channel entry {i + 1} ({topic}{f':{fld}' if fld else ''})"


def _build_entry(entry: Any, i: int, topics: Counter[str], source: str) -> ChannelSpec:
    where = _where(source, i, entry)
    if not isinstance(entry, dict):
        raise SpecError(f"{where}: an entry is a table with topic, field and role")
    unknown = sorted(set(entry) - set(_ENTRY_KEYS))
    if unknown:
        raise SpecError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(_ENTRY_KEYS)})")
    for key in ("topic", "role"):
        if not isinstance(entry.get(key), str) or not entry[key]:
            raise SpecError(f"{where}: `{key}` is required (a string)")
    if entry["role"] not in ROLES:
        raise SpecError(f"{where}: role must be \"action\" or \"observation\", not {entry['role']!r}")
    fld = entry.get("field", "")
    if not isinstance(fld, str):
        raise SpecError(f"{where}: `field` must be a string")
    if not isinstance(entry.get("name", ""), str):
        raise SpecError(f"{where}: `name` must be a string")
    try:
        parse_field_path(fld)
    except FieldPathError as err:
        raise SpecError(f"{where}: {err}") from err
    name = entry.get("name") or (entry["topic"] if topics[entry["topic"]] == 1 or not fld
                                 else f"{entry['topic']}:{fld}")
    mode = entry.get("mode")
    if mode is not None and mode not in CHANNEL_MODES:
        raise SpecError(f"{where}: an entry's mode must be \"message\" or \"change\", not "
                        f"{_shown(mode)}")
    max_symbols = _max_symbols(entry, where)
    limit = max_symbols or MAX_SYMBOLS
    actions = entry.get("actions")
    if actions is not None:
        if entry["role"] != OBSERVATION:
            raise SpecError(f"{where}: `actions` belongs to observation entries (the actions that "
                            f"drive them); drop it from this action entry")
        if not isinstance(actions, list) or not all(isinstance(a, str) and a for a in actions) \
                or len(actions) > MAX_CHANNELS:
            raise SpecError(f"{where}: `actions` must be a list of action entry names, not {_shown(actions)}")
        actions = tuple(dict.fromkeys(actions))
    return ChannelSpec(entry["topic"], fld, entry["role"], name,
                       _build_symbolizer(entry, where, limit), max_symbols=max_symbols, mode=mode,
                       actions=actions)


def _max_symbols(entry: dict, where: str) -> int | None:
    if "max_symbols" not in entry:
        return None
    value = entry["max_symbols"]
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_SYMBOLS_LIMIT:
        raise SpecError(f"{where}: `max_symbols` must be an integer from 1 to {MAX_SYMBOLS_LIMIT:,}, "
                        f"not {_shown(value)}")
    return value


def _numbers(value: Any, key: str, where: str) -> tuple[float, ...]:
    if not isinstance(value, list) or not all(_is_number(v) for v in value):
        raise SpecError(f"{where}: `{key}` must be a list of finite numbers")
    return tuple(float(v) for v in value)


def _count(value: Any, key: str, where: str, limit: int) -> int:
    """A positive integer of at most ``limit`` (symbols of the channel)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= limit:
        raise SpecError(f"{where}: `{key}` must be an integer from 1 to {limit:,} (the channel's "
                        f"symbol limit; raise it with max_symbols), not {_shown(value)}")
    return value


def _increasing(value: Any, key: str, where: str, limit: int) -> tuple[float, ...]:
    edges = _numbers(value, key, where)
    if not edges or any(a >= b for a, b in zip(edges, edges[1:])):
        raise SpecError(f"{where}: `{key}` must be a non-empty, strictly increasing list")
    if len(edges) >= limit:
        raise SpecError(f"{where}: `{key}` makes {len(edges) + 1:,} bins; at most {limit:,} "
                        f"(raise it with max_symbols)")
    return edges


def _values(value: Any, where: str, limit: int) -> tuple:
    if not isinstance(value, list):
        raise SpecError(f"{where}: `values` must be a list of distinct values")
    for v in value:
        if not isinstance(v, (str, int, float)) or isinstance(v, float) and not math.isfinite(v):
            raise SpecError(f"{where}: `values` may hold strings, integers, finite numbers and "
                            f"booleans, not {_shown(v)}")
    if len(set(value)) != len(value):
        raise SpecError(f"{where}: `values` must be distinct (1, 1.0 and true are the same value)")
    if len(value) > limit:
        raise SpecError(f"{where}: {len(value):,} `values`; at most {limit:,} (raise it with max_symbols)")
    return tuple(value)


def _build_symbolizer(entry: dict, where: str, limit: int) -> Symbolizer:
    kinds = [k for k in ("width", "range", "quantiles") if k in entry]
    if "edges" in entry and "quantiles" not in entry:
        kinds.append("edges")
    stray = [k for k in _BIN_KEYS if k in entry]
    if "values" in entry and stray:
        raise SpecError(f"{where}: `values` (categorical) cannot be combined with `{stray[0]}` (bins)")
    if "values" in entry:
        return Categorical(_values(entry["values"], where, limit))
    if not kinds:
        if stray:
            raise SpecError(f"{where}: `{stray[0]}` needs one of width, range (+count), edges, quantiles")
        return Categorical()
    if len(kinds) > 1:
        raise SpecError(f"{where}: choose one binning: {' or '.join(kinds)}")
    return _build_bins(entry, kinds[0], where, limit)


def _build_bins(entry: dict, kind: str, where: str, limit: int) -> Bins:
    bins = _build_bins_kind(entry, kind, where, limit)
    clip, unit = entry.get("clip", False), entry.get("unit")
    if not isinstance(clip, bool):
        raise SpecError(f"{where}: `clip` must be true or false")
    if clip and (kind != "range" or bins.wrap):
        raise SpecError(f"{where}: `clip` goes with `range` (values outside it are put in the "
                        f"end bins)")
    if unit is not None and (not isinstance(unit, str) or not unit.strip()):
        raise SpecError(f"{where}: `unit` must be a short text such as \"rad\", \"deg\" or \"m\"")
    return replace(bins, clip=clip, unit=unit)


def _build_bins_kind(entry: dict, kind: str, where: str, limit: int) -> Bins:
    wrap = entry.get("wrap", False)
    if not isinstance(wrap, bool):
        raise SpecError(f"{where}: `wrap` must be true or false")
    if wrap and kind != "range":
        raise SpecError(f"{where}: `wrap` needs `range` (the period) and `count`")
    if kind == "width":
        return _width_bins(entry, where)
    if kind == "range":
        lo_hi = _numbers(entry["range"], "range", where)
        if len(lo_hi) != 2 or not lo_hi[0] < lo_hi[1] or not math.isfinite(lo_hi[1] - lo_hi[0]):
            raise SpecError(f"{where}: `range` must be [low, high] with low < high, both finite")
        if "count" not in entry:
            raise SpecError(f"{where}: `range` needs `count`, the number of bins")
        return Bins(range=lo_hi, count=_count(entry["count"], "count", where, limit), wrap=wrap)
    if kind == "edges":
        return Bins(edges=_increasing(entry["edges"], "edges", where, limit))
    quantiles = _count(entry["quantiles"], "quantiles", where, limit)
    fitted = _numbers(entry["edges"], "edges", where) if "edges" in entry else None
    if fitted is not None and (len(fitted) >= quantiles or any(a >= b for a, b in zip(fitted, fitted[1:]))):
        raise SpecError(f"{where}: fitted `edges` must be strictly increasing, fewer than `quantiles`")
    return Bins(quantiles=quantiles, edges=fitted)


def _width_bins(entry: dict, where: str) -> Bins:
    width, origin = entry["width"], entry.get("origin", 0.0)
    lo, hi = WIDTH_RANGE
    if not _is_number(width) or not lo <= width <= hi:
        raise SpecError(f"{where}: `width` must be a number from {lo:g} to {hi:g}, not {_shown(width)}")
    if not _is_number(origin) or abs(origin) > MAX_ORIGIN:
        raise SpecError(f"{where}: `origin` must be a finite number within +-{MAX_ORIGIN:g}, "
                        f"not {_shown(origin)}")
    return Bins(width=float(width), origin=float(origin))


# --- CLI shorthand ------------------------------------------------------------------------

def _literal(text: str) -> Any:
    """``"3"`` -> 3, ``"0.5"`` -> 0.5, ``"true"`` -> True, anything else stays text."""
    for convert in (int, float):
        try:
            return convert(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def _option_items(value: str) -> list:
    inner = value.strip()
    if inner.startswith("[") and inner.endswith("]"):
        inner = inner[1:-1]
        return [_literal(v.strip().strip("'\"")) for v in inner.replace(";", ",").split(",") if v.strip()]
    return [_literal(v) for v in value.split(";")]


def parse_channel_option(text: str) -> dict:
    """Parse ``TOPIC:FIELD:ROLE[:OPTIONS]`` into a spec entry table (see the module doc).

    OPTIONS: ``key=value`` pairs separated by commas; lists as ``[a,b]`` or ``a;b``:
    ``range=[0,6.28],count=36,wrap=true``, ``values=[L,R]``, ``mode=change``,
    ``actions=[/cmd:data[0]]``.

    Raises:
        SpecError: fewer than three parts or a malformed option.
    """
    parts = split_outside_brackets(text, ":", 3)  # TOPIC:FIELD:ROLE:OPTIONS
    if len(parts) < 3:
        raise SpecError(f"--channel {text!r}: expected TOPIC:FIELD:ROLE[:OPTIONS], "
                        f"e.g. /pointer/command:command:action:values=[L,R]")
    entry: dict[str, Any] = {"topic": parts[0], "field": parts[1], "role": parts[2]}
    for option in (split_outside_brackets(parts[3], ",") if len(parts) == 4 and parts[3] else []):
        key, eq, value = option.partition("=")
        if not eq or not key.strip():
            raise SpecError(f"--channel {text!r}: option {option!r} must be key=value "
                            f"(lists as key=[a,b])")
        items = _option_items(value)
        listy = key.strip() in ("values", "edges", "range", "actions") or len(items) > 1
        entry[key.strip()] = items if listy else (items[0] if items else "")
    return entry


def spec_from_options(channels: Iterable[str], mode: str = DEFAULT_MODE,
                      tick_ms: float | None = None, phase_ms: float | None = None) -> Spec:
    """Build a spec from ``--channel`` shorthands, a mode, an optional tick period and phase."""
    data: dict[str, Any] = {"mode": mode, "channel": [parse_channel_option(c) for c in channels]}
    if tick_ms is not None:
        data["tick_ms"] = tick_ms
    if phase_ms is not None:
        data["phase_ms"] = phase_ms
    return _build_spec(data, "--channel options")


# --- built-in specs -----------------------------------------------------------------------

POINTER_COMMAND = "/pointer/command"
POINTER_POSITION = "/pointer/position"
POINTER_BINS = 36


def pointer_spec() -> Spec:
    """The pointer logs' spec: ``/pointer/command`` (action, ``L``/``R``) and
    ``/pointer/position`` (observation, labels 1..36), every message an event.

    With a fresh vocabulary the symbols are ``L`` = 0, ``R`` = 1, position ``k`` = ``k + 1``
    (``/pointer/angle`` is ground truth and not read).
    """
    return Spec((
        ChannelSpec(POINTER_COMMAND, "command", ACTION, POINTER_COMMAND, Categorical(("L", "R"))),
        ChannelSpec(POINTER_POSITION, "position", OBSERVATION, POINTER_POSITION,
                    Categorical(tuple(range(1, POINTER_BINS + 1)))),
    ), mode="message", source="pointer_spec()")
