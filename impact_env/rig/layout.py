"""Message layouts declared as data: each payload field once, as a :class:`Field` (wire type, range,
unit, meaning), from which :func:`message` derives a payload class's ``struct`` format, its checks,
its encoding and decoding, the offsets the compiled wire reads (:mod:`impact_env.rig.wire`) and the
docs' tables (docs/_ext/generated_reference.py).

A payload is its fixed part (the fields in declaration order, little-endian, then ``PAD`` zero
bytes), then the variable fields' contents in declaration order.  A variable field (``floats``,
``data``, ``text``) holds its count (a u16) at its place in the fixed part.

A value out of its declared range raises :class:`FieldError` (naming the field, its range and its
unit; an authenticated request is answered with its terse ``refusal``); a value of the wrong type
or shape raises ValueError (to a receiver: a corrupt payload).
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, TypeVar

U8, U16, U32, U64 = 0xFF, 0xFFFF, 0xFFFF_FFFF, 0xFFFF_FFFF_FFFF_FFFF
# the wire types: struct code, and the largest value of the integer ones
_INTS = {"u8": ("B", U8), "u16": ("H", U16), "u32": ("I", U32), "u64": ("Q", U64)}
_CODES = {**{k: code for k, (code, _) in _INTS.items()}, "f64": "d", "bool": "B", "enum": "B", "choice": "B",
          "floats": "H", "data": "H", "text": "H"}
VARIABLE = frozenset({"floats", "data", "text"})  # a u16 count in the fixed part, the contents after it


# -- errors ------------------------------------------------------------------------------------------
class ProtocolError(ValueError):
    """A datagram that cannot be decoded; ``reason`` is the :class:`DatagramFilter` counter it
    goes to, ``detail`` says why."""

    reason = "corrupt"

    def __init__(self, detail: str, message: str):
        super().__init__(message)
        self.detail = detail


class CorruptDatagram(ProtocolError):
    """Bad magic, length or payload (``detail``: truncated, magic, length, payload)."""


class FieldError(ValueError):
    """A field out of its range: ``field`` and the terse ``refusal`` (``field=value [range]``)."""

    def __init__(self, message: str, field: str, refusal: str):
        super().__init__(message)
        self.field, self.refusal = field, refusal


# -- fields ------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Field:
    """One field of a payload or of the header.

    kind: ``u8``/``u16``/``u32``/``u64`` (an int in [low, high]; high None: the type's largest);
    ``f64`` (a finite float > low); ``bool`` (a u8, 0 or 1); ``enum`` (a str of ``choices``, sent
    as its code); ``choice`` (an int of ``choices``, which maps each to its meaning; a u8);
    ``bytes`` (exactly ``size`` bytes); ``floats`` (a tuple of low..high floats, as f64, or as the
    float of the size that the field named ``elem`` holds: 4 or 8 bytes); ``data`` (bytes, at most
    high); ``text`` (a str of at most high UTF-8 bytes).
    """

    name: str
    kind: str
    low: float = 0
    high: float | None = None
    unit: str = ""
    meaning: str = ""
    choices: Mapping[Any, Any] | None = None
    size: int = 0
    elem: str = ""

    @property
    def code(self) -> str:
        return f"{self.size}s" if self.kind == "bytes" else _CODES[self.kind]

    @property
    def top(self) -> float:
        if self.high is not None:
            return self.high
        return _INTS[self.kind][1] if self.kind in _INTS else U16

    def range_text(self) -> str:
        """The field's range as the docs' table gives it."""
        k = self.kind
        if k in _INTS:
            return f"[{int(self.low)}, {int(self.top)}]"
        if k == "f64":
            return f"> {self.low:g}"
        if k == "bool":
            return "0, 1"
        if k in ("enum", "choice"):
            choices = dict(self.choices or {})
            pairs = choices.items() if k == "choice" else ((c, n) for n, c in choices.items())
            return ", ".join(f"{c} {n}" for c, n in pairs)
        if k in VARIABLE:
            return f"count [{int(self.low)}, {int(self.top)}]"
        return ""

    def check(self, value: Any) -> None:
        """Raise FieldError (out of range) or ValueError (wrong type) unless ``value`` fits."""
        k, name = self.kind, self.name
        if k in _INTS:
            check_uint(name, value, int(self.top), int(self.low), self.unit)
        elif k == "f64":
            if not (isinstance(value, float) and value > self.low and math.isfinite(value)):
                raise ValueError(f"{name} = {value!r} {self.unit} must be a finite float > {self.low:g} "
                                 f"{self.unit}")
        elif k == "bool":
            if not isinstance(value, bool):
                raise ValueError(f"{name} must be a bool, got {value!r}")
        elif k in ("enum", "choice"):
            if value not in self.choices:  # type: ignore[operator]
                one_of = ", ".join(self.choices or {}) if k == "enum" else self.range_text()
                raise ValueError(f"{name} = {value!r} must be one of {one_of}")
        elif k == "bytes":
            if not isinstance(value, bytes) or len(value) != self.size:
                raise ValueError(f"{name} must be {self.size} bytes ({self.meaning}), got {value!r:.80}")
        elif k == "floats":
            lo, hi = int(self.low), int(self.top)
            if not isinstance(value, tuple) or not lo <= len(value) <= hi:
                n = len(value) if hasattr(value, "__len__") else "?"
                raise FieldError(f"{name} must be a tuple of {lo} to {hi} floats, got "
                                 f"{type(value).__name__} of length {n}", name, f"n={n} [{lo},{hi}]")
            for v in value:
                if type(v) is not float:
                    raise ValueError(f"{name} must hold Python floats, got {v!r} ({type(v).__name__})")
        elif k == "data":
            if not isinstance(value, bytes) or len(value) > self.top:
                raise ValueError(f"{name} must be bytes of at most {int(self.top)} B, got "
                                 f"{type(value).__name__}"
                                 f"{'' if not isinstance(value, bytes) else f' of {len(value)} B'}")
        elif k == "text":
            if not isinstance(value, str) or len(value.encode("utf-8", "surrogatepass")) > self.top:
                raise ValueError(f"{name} must be a str of at most {int(self.top)} UTF-8 bytes")
            try:
                value.encode("utf-8")
            except UnicodeEncodeError as exc:
                raise ValueError(f"{name} is not encodable as UTF-8: {exc}") from None

    def fits(self) -> Callable[[Any], bool]:
        """Whether a value fits, the common case first and fast (every field of every payload
        made is checked); :meth:`check` says why one does not."""
        lo, hi, size, choices = self.low, self.top, self.size, dict(self.choices or {})
        if self.kind in _INTS:
            return lambda v: type(v) is int and lo <= v <= hi
        return {"f64": lambda v: type(v) is float and v > lo and math.isfinite(v),
                "bool": lambda v: type(v) is bool,
                "enum": lambda v: v in choices,
                "choice": lambda v: v in choices,
                "bytes": lambda v: type(v) is bytes and len(v) == size,
                "floats": lambda v: (type(v) is tuple and lo <= len(v) <= hi
                                     and all(type(x) is float for x in v)),
                "data": lambda v: type(v) is bytes and len(v) <= hi,
                }.get(self.kind, lambda v: False)

    def decoder(self, mtype: Any) -> Callable[[Any], Any]:
        """The value of a decoded field from its wire value, checked (a field :meth:`checked_on_decode`)."""
        if self.kind == "enum":
            names = {c: n for n, c in dict(self.choices or {}).items()}
            text = f"{mtype.name} {self.name} {{}} unknown: {self.range_text()}"
            refusal = f"{self.name}={{}} [{min(names)},{max(names)}]"

            def enum_name(v: int) -> str:
                if v not in names:
                    raise FieldError(text.format(v), self.name, refusal.format(v))
                return names[v]
            return enum_name
        if self.kind == "bool":
            def boolean(v: int) -> bool:
                if v > 1:
                    raise ValueError(f"{self.name} byte {v} is not 0 or 1")
                return bool(v)
            return boolean
        lo, hi = self.low, self.top
        # decoded floats are floats: their count is what to check
        fits = (lambda v: lo <= len(v) <= hi) if self.kind == "floats" else self.fits()

        def checked(v: Any) -> Any:
            if not fits(v):
                self.check(v)
            return v
        return checked

    def checked_on_decode(self) -> bool:
        """Whether a decoded value can be out of range (else the wire type holds only good ones)."""
        if self.kind in _INTS:
            return (self.low, self.top) != (0, _INTS[self.kind][1])
        return self.kind in ("f64", "bool", "enum", "choice", "text") or (
            self.kind == "floats" and (self.low, self.top) != (0, U16))


def check_uint(name: str, value: Any, hi: int, lo: int = 0, unit: str = "") -> None:
    if type(value) is int and lo <= value <= hi:  # the common case, first: decoding runs it per field
        return
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise FieldError(f"{name} = {value!r} must be an integer in [{lo}, {hi}]{' ' + unit if unit else ''}",
                         name, f"{name}={value!r:.24} [{lo},{hi}]")


def wire(kind: str, default: Any, low: float = 0, high: float | None = None, unit: str = "",
         meaning: str = "", *, choices: Mapping | None = None, size: int = 0, elem: str = "") -> Any:
    """A payload class's field: its default, and its :class:`Field` (named by :func:`message`)."""
    return dataclasses.field(default=default, metadata={"wire": Field("", kind, low, high, unit, meaning,
                                                                      choices, size, elem)})


def fmt_of(fields: tuple[Field, ...], pad: int = 0) -> struct.Struct:
    """The ``struct`` of the fixed part of ``fields`` (then ``pad`` zero bytes)."""
    return struct.Struct("<" + "".join(f.code for f in fields) + (f"{pad}x" if pad else ""))


def offsets_of(fields: tuple[Field, ...]) -> dict[str, int]:
    """Each field's offset in the fixed part (a variable field's: its count's)."""
    out, at = {}, 0
    for f in fields:
        out[f.name] = at
        at += struct.calcsize("<" + f.code)
    return out


# -- payload classes ---------------------------------------------------------------------------------
def _need(payload, n: int, newer: bool, exact: bool) -> None:
    if len(payload) < n or (exact and not newer and len(payload) != n):
        raise CorruptDatagram("payload", f"payload of {len(payload)} B where {n} B are needed")


class Body:
    """A message payload.  :func:`message` derives ``FIELDS``, ``FMT`` and ``OFFSETS`` from the
    dataclass fields' declarations; a subclass fixes ``TYPE`` (and ``PAD``), and may add checks
    across fields in ``check``."""

    TYPE: ClassVar[Any]  # the protocol's MsgType
    PAD: ClassVar[int] = 0  # zero bytes after the fixed part
    FIELDS: ClassVar[tuple[Field, ...]]
    FMT: ClassVar[struct.Struct]
    OFFSETS: ClassVar[dict[str, int]]
    # derived by message(): the field names; each field's fits(); the decoded fields' (name, decoder);
    # whether any field is variable; whether the fixed part packs the attributes as they are
    _NAMES: ClassVar[tuple[str, ...]]
    _FITS: ClassVar[tuple[Callable[[Any], bool], ...]]
    _DECODERS: ClassVar[tuple[tuple[str, Callable[[Any], Any]], ...]]
    _VARIABLE: ClassVar[bool]
    _PLAIN: ClassVar[bool]
    _ENUMS: ClassVar[tuple[tuple[int, Mapping[Any, int]], ...]]  # (index, code of each name)
    # the variable fields: (index, kind, elem, elem's check)
    _VARS: ClassVar[tuple[tuple[int, str, str, Callable[[Any], None]], ...]]

    def __post_init__(self) -> None:
        for fits, f in zip(self._FITS, self.FIELDS, strict=True):
            value = getattr(self, f.name)
            if not fits(value):
                f.check(value)
        self.check()

    def check(self) -> None:
        """Checks across fields, after each field's own (construction and decoding)."""

    def pack(self) -> bytes:
        values = [getattr(self, name) for name in self._NAMES]
        if self._PLAIN:
            return self.FMT.pack(*values)
        for i, codes in self._ENUMS:
            values[i] = codes[values[i]]
        tail = []
        for i, kind, elem, _ in self._VARS:
            v = values[i]
            if kind == "floats":
                tail.append(struct.pack(f"<{len(v)}{'f' if elem and getattr(self, elem) == 4 else 'd'}", *v))
                values[i] = len(v)
            else:
                tail.append(v.encode("utf-8") if kind == "text" else v)
                values[i] = len(tail[-1])
        return self.FMT.pack(*values) + b"".join(tail)

    @classmethod
    def unpack(cls, payload: bytes | memoryview, newer: bool) -> Body:
        """Decode ``payload``; ``newer``: the sender's minor is newer (trailing bytes allowed)."""
        fixed = cls.FMT.size
        _need(payload, fixed, newer, exact=not cls._VARIABLE)
        raw = cls.FMT.unpack_from(payload)
        values = dict(zip(cls._NAMES, raw, strict=True))
        if cls._VARIABLE:
            at, parts = fixed, []
            for i, kind, elem, check_elem in cls._VARS:
                size = 1 if kind != "floats" else 8 if not elem else values[elem]
                if elem:  # the size of the floats to come: checked before they are read
                    check_elem(size)
                parts.append((cls._NAMES[i], kind, at, raw[i], size))
                at += size * raw[i]
            _need(payload, at, newer, exact=True)
            for name, kind, start, n, size in parts:
                if kind == "floats":
                    values[name] = struct.unpack_from(f"<{n}{'f' if size == 4 else 'd'}", payload, start)
                elif kind == "data":
                    values[name] = bytes(payload[start:start + n])
                else:
                    try:
                        values[name] = bytes(payload[start:start + n]).decode("utf-8")
                    except UnicodeDecodeError as exc:
                        raise ValueError(f"{name} is not UTF-8: {exc}") from None
        for name, decoded in cls._DECODERS:
            values[name] = decoded(values[name])
        # every other field is in range by construction (struct): a decoded payload skips their checks
        out = object.__new__(cls)
        out.__dict__.update(values)
        out.check()
        return out

    @classmethod
    def declared(cls, name: str) -> Field:
        return next(f for f in cls.FIELDS if f.name == name)


BodyClass = TypeVar("BodyClass", bound=type[Body])


def message(cls: BodyClass) -> BodyClass:
    """Derive a payload dataclass's ``FIELDS``, ``FMT`` and ``OFFSETS`` from its declarations."""
    declared: Any = cls  # a dataclass (message is applied above @dataclass)
    decl = tuple(dataclasses.replace(f.metadata["wire"], name=f.name) for f in dataclasses.fields(declared))
    cls.FIELDS = decl
    cls.FMT = fmt_of(decl, cls.PAD)
    cls.OFFSETS = offsets_of(decl)
    cls._NAMES = tuple(f.name for f in decl)
    cls._FITS = tuple(f.fits() for f in decl)
    cls._DECODERS = tuple((f.name, f.decoder(cls.TYPE)) for f in decl if f.checked_on_decode())
    cls._VARIABLE = any(f.kind in VARIABLE for f in decl)
    cls._PLAIN = not cls._VARIABLE and not any(f.kind == "enum" for f in decl)
    cls._ENUMS = tuple((i, dict(f.choices or {})) for i, f in enumerate(decl) if f.kind == "enum")
    cls._VARS = tuple((i, f.kind, f.elem, cls.declared(f.elem).check if f.elem else f.check)
                      for i, f in enumerate(decl) if f.kind in VARIABLE)
    return cls
