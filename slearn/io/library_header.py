"""The library header: the small JSON document in a library file's metadata, and its schema.

A library's header is read before anything else of the file and validated against the
schema of its format version before any of it is used, so a damaged or hand-edited header
gives one line naming the field (``params.max_length``, ``library.rows.token``, ...)
instead of an exception deep inside loading, and never an allocation sized by a number
it holds.

The schema is declarative: :data:`HEADER` maps each field to a :class:`Field` (JSON type,
required or not, range, choices, nested fields, extra checks, the format version that
introduced it). To extend the format, bump :data:`FORMAT_VERSION` and add fields with
``since=`` the new version; documents of older versions are validated without them.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from os import PathLike
from typing import Any, Callable, Mapping

from slearn import __version__
from slearn.core.library import MAX_MAX_LENGTH
from slearn.core.library import MAX_PATTERNS as MAX_BOUND
from slearn.errors import LibraryFormatError, SpecError

FORMAT_NAME = "slearn-library"
FORMAT_VERSION = 6
OLDEST_READ = 2
"""The oldest format version read: version 5 is version 6 without the views' persistence
specialists, version 4 is version 5 without the views' rounds,
version 3 is version 4 without the detectors' calibration counts, version 2 is version 3
without action scopes."""
TABLES = ("vocabulary", "token", "view", "pattern")

MAX_HEADER_BYTES = 64 << 20
MAX_DEPTH = 32
MAX_LENGTH = MAX_MAX_LENGTH     # steps a context spans (also the bound of --max-length)
MAX_PATTERNS = MAX_BOUND        # patterns are rows of int32-indexed tables
MAX_ROWS = 1 << 40
MAX_CLOCK = 1 << 62
MAX_TIME_UNIX = 253402300799    # 9999-12-31T23:59:59Z, the last second datetime can show
SCORING_RULES = ("adaptive", "literal")

_SHA256 = re.compile(r"[0-9a-f]{64}")
_KINDS = {"int": "an integer", "number": "a number", "str": "a string", "bool": "true or false",
          "list": "a list", "object": "an object"}

Check = Callable[[Any, str], "str | None"]


@dataclass(frozen=True)
class Field:
    """One header field.

    Attributes:
        kind: the JSON type: ``int``, ``number``, ``str``, ``bool``, ``list``, ``object``
            or ``any``.
        required: whether the field must be present.
        nullable: whether ``null`` is allowed.
        low, high: the range of a number (inclusive).
        choices: the allowed values.
        fields: an object's known fields (other fields are allowed and kept as they are).
        items: the field of every item of a list.
        max_items: the longest list or string.
        check: a further check ``check(value, where)`` after the type; returns the problem
            (naming ``where``), or ``None``.
        since: the format version that introduced the field.
    """

    kind: str
    required: bool = True
    nullable: bool = False
    low: float | None = None
    high: float | None = None
    choices: tuple | None = None
    fields: Mapping[str, "Field"] | None = None
    items: "Field | None" = None
    max_items: int | None = None
    check: Check | None = None
    since: int = 1


def _scoring(value: Any, where: str) -> str | None:
    """A scoring rule name, or ``{rule, alpha, buckets, prior}``."""
    if isinstance(value, dict):
        return _problem(value, _SCORING_FIELDS, f"{where}.", 1)
    if value not in SCORING_RULES:
        return _wrong(where, value, f"must be one of {', '.join(SCORING_RULES)} or an object")
    return None


def _pair(value: Any, where: str) -> str | None:
    """``[channel name, role]``."""
    if not (len(value) == 2 and isinstance(value[0], str) and value[1] in ("action", "observation")):
        return _wrong(where, value, 'must be [channel name, "action" | "observation"]')
    return None


def _scopes(value: Any, where: str) -> str | None:
    """``{observation channel: [action channel, ...]}``."""
    for view, names in value.items():
        if not (isinstance(names, list) and len(names) <= 1 << 20 and all(isinstance(n, str) for n in names)):
            return _wrong(f"{where}.{view}", names, "must be a list of action channel names")
    return None


def _sha256(value: Any, where: str) -> str | None:
    return None if _SHA256.fullmatch(value) else _wrong(where, value, "must be 64 lowercase hex digits")


def _spec(value: Any, where: str) -> str | None:
    from slearn.io.spec import Spec

    try:
        Spec.from_dict(value, f"field {where}")
    except SpecError as err:
        return str(err)
    return None


_SCORING_FIELDS = {
    "rule": Field("str", choices=SCORING_RULES),
    "alpha": Field("number", required=False, low=1e-9, high=1.0),
    "buckets": Field("int", required=False, low=1, high=64),
    "prior": Field("number", required=False, low=0.0, high=1.0),
}
_FILE_RECORD = Field("object", fields={
    "path": Field("str", max_items=4096),
    "size_bytes": Field("int", low=0, high=(1 << 63) - 1),
    "sha256": Field("str", check=_sha256),
})

HEADER: dict[str, Field] = {
    "format": Field("str"),
    "version": Field("int", low=1),
    "params": Field("object", fields={
        "max_length": Field("int", low=1, high=MAX_LENGTH),
        "max_patterns": Field("int", nullable=True, low=16, high=MAX_PATTERNS),
        "scoring": Field("any", required=False, check=_scoring),
        "factored": Field("bool", required=False, since=2),
        "has_actions": Field("bool", required=False, since=2),
        "form": Field("str", required=False, choices=("sequence", "steps"), since=2),
        "action_scopes": Field("object", required=False, check=_scopes, since=3),
    }),
    "library": Field("object", fields={
        "clock": Field("int", low=0, high=MAX_CLOCK),
        "forgotten": Field("int", low=0, high=MAX_CLOCK),
        "patterns": Field("int", low=0, high=MAX_PATTERNS),
        "channels": Field("list", max_items=1 << 20, items=Field("list", check=_pair)),
        "rows": Field("object", fields={t: Field("int", low=0, high=MAX_ROWS,
                                                 since=2 if t == "view" else 1) for t in TABLES}),
    }),
    "spec": Field("object", nullable=True, check=_spec),
    "provenance": Field("object", fields={
        "slearn_version": Field("str", required=False, max_items=64),
        "inputs": Field("list", required=False, items=_FILE_RECORD),
        "merged_from": Field("list", required=False, items=_FILE_RECORD),
        "time": Field("str", required=False, max_items=64),
        "time_unix": Field("int", required=False, low=0, high=MAX_TIME_UNIX),
        "time_source": Field("str", required=False, max_items=256),
    }),
}


def parse_header(raw: bytes, path: str | PathLike) -> dict:
    """Parse and validate a library header; return the document.

    Raises:
        LibraryFormatError: not JSON, too large or too deep, another format, a newer
            version, or a field that breaks the schema; one line naming the field.
    """
    if len(raw) > MAX_HEADER_BYTES:
        raise _error(path, f"the header is {len(raw):,} bytes (at most {MAX_HEADER_BYTES:,})")
    try:
        doc = json.loads(raw, parse_constant=_no_constant)
    except (ValueError, RecursionError) as err:  # UnicodeDecodeError is a ValueError
        raise _error(path, f"the header is not valid JSON ({type(err).__name__}: "
                           f"{' '.join(str(err).split())[:120]})") from err
    validate_header(doc, path)
    return doc


def validate_header(doc: Any, path: str | PathLike) -> None:
    """Check a parsed header against the schema of its version (see :func:`parse_header`)."""
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
        shown = repr(doc.get("format"))[:60] if isinstance(doc, dict) else None
        raise LibraryFormatError(f"{path}: a Parquet file, but not a slearn pattern library "
                                 f"(format {shown}): make libraries with `slearn learn`")
    version = doc.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise LibraryFormatError(f"{path}: invalid library format version {repr(version)[:60]}: "
                                 "re-create the library with `slearn learn`")
    if version > FORMAT_VERSION:
        raise LibraryFormatError(f"{path}: library format version {version} is newer than this "
                                 f"slearn {__version__} reads (up to {FORMAT_VERSION}): upgrade slearn")
    if version < OLDEST_READ:
        raise LibraryFormatError(f"{path}: library format version {version} (slearn 0.1) counted "
                                 f"patterns only at parse boundaries; this slearn reads formats "
                                 f"{OLDEST_READ}-{FORMAT_VERSION}: learn the logs again with `slearn learn`")
    if _depth(doc) > MAX_DEPTH:
        raise _error(path, f"the header nests deeper than {MAX_DEPTH} levels")
    problem = _problem(doc, HEADER, "", version) or _consistency(doc)
    if problem:
        raise _error(path, problem)


def _consistency(doc: dict) -> str | None:
    library = doc["library"]
    if library["patterns"] != library["rows"]["pattern"]:
        return (f"field library.patterns ({library['patterns']}) differs from "
                f"library.rows.pattern ({library['rows']['pattern']})")
    names = [name for name, _ in library["channels"]]
    if len(set(names)) != len(names):
        return "field library.channels names a channel twice"
    return None


def _problem(obj: dict, fields: Mapping[str, Field], prefix: str, version: int) -> str | None:
    """What is wrong with the known fields of an object, or ``None``."""
    for name, spec in fields.items():
        where = f"{prefix}{name}"
        if name not in obj:
            if spec.required and spec.since <= version:
                return f"field {where} is missing"
            continue
        problem = _value_problem(obj[name], spec, where, version)
        if problem:
            return problem
    return None


def _value_problem(value: Any, spec: Field, where: str, version: int) -> str | None:
    if value is None:
        return None if spec.nullable else f"field {where} must not be null"
    wrong = _type_problem(value, spec)
    if wrong is None and spec.choices is not None and value not in spec.choices:
        wrong = f"must be one of {', '.join(map(str, spec.choices))}"
    if wrong:
        return _wrong(where, value, wrong)
    if spec.check is not None:
        problem = spec.check(value, where)
        if problem:
            return problem
    if spec.fields is not None:
        return _problem(value, spec.fields, f"{where}.", version)
    if spec.items is not None:
        for i, item in enumerate(value):
            problem = _value_problem(item, spec.items, f"{where}[{i}]", version)
            if problem:
                return problem
    return None


def _wrong(where: str, value: Any, text: str) -> str:
    return f"field {where} {text}, not {_shown(value)}"


def _type_problem(value: Any, spec: Field) -> str | None:
    kind = spec.kind
    ok = {"int": isinstance(value, int) and not isinstance(value, bool),
          "number": isinstance(value, (int, float)) and not isinstance(value, bool),
          "str": isinstance(value, str), "bool": isinstance(value, bool),
          "list": isinstance(value, list), "object": isinstance(value, dict), "any": True}[kind]
    if not ok:
        return f"must be {_KINDS[kind]}"
    if kind in ("int", "number") and not _within(value, spec.low, spec.high):
        return f"must be {_KINDS[kind]} from {_num(spec.low)} to {_num(spec.high)}"
    if spec.max_items is not None and kind in ("list", "str") and len(value) > spec.max_items:
        unit = "characters" if kind == "str" else "items"
        return f"must hold at most {spec.max_items:,} {unit}"
    return None


def _within(value: float, low: float | None, high: float | None) -> bool:
    if isinstance(value, float) and not math.isfinite(value):
        return False
    return (low is None or value >= low) and (high is None or value <= high)


def _num(x: float | None) -> str:
    if x is None:
        return "any"
    return f"{x:,}" if isinstance(x, int) else f"{x:g}"


def _depth(doc: Any) -> int:
    """Nesting depth of lists and objects, without recursion."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        obj, depth = stack.pop()
        if isinstance(obj, (dict, list)):
            deepest = max(deepest, depth)
            if depth <= MAX_DEPTH:
                stack.extend((v, depth + 1) for v in (obj.values() if isinstance(obj, dict) else obj))
    return deepest


def _shown(value: Any) -> str:
    text = repr(value) if not isinstance(value, (dict, list)) else type(value).__name__
    return text if len(text) <= 60 else text[:57] + "..."


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a JSON number")


def _error(path: str | PathLike, problem: str) -> LibraryFormatError:
    return LibraryFormatError(f"{path}: damaged library header: {problem}: re-create the "
                              f"library with `slearn learn`")
