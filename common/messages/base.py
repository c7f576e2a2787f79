"""The message machinery: a typed, versioned base, one codec, one error type.

Every wire type derives from :class:`Message`. It is a frozen msgspec struct,
tagged with its class name in the ``type`` field and carrying its schema version
in ``v``. The wire format is plain MessagePack (any MessagePack library reads
it); msgspec validates field types and constraints while it decodes, so a
malformed or hostile payload becomes one :class:`MessageError`.
"""

from __future__ import annotations

import functools
from typing import Annotated, Any, Literal, TypeVar, Union, cast, overload

import msgspec
import numpy as np

# The largest payload any process decodes. Bulk frames of 1,000 robots are
# about 20 KB and uploaded controllers are capped far lower (see agent
# messages); 16 MiB leaves room for large map snapshots and nothing more.
MAX_MESSAGE_BYTES = 16 * 1024 * 1024

# --- constrained field types --------------------------------------------------

IDENT_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}$"
Ident = Annotated[str, msgspec.Meta(pattern=IDENT_PATTERN, max_length=64)]
"""A name usable as one key chunk: users, contexts, worlds, agents, hosts."""

ShortText = Annotated[str, msgspec.Meta(max_length=256)]
Text = Annotated[str, msgspec.Meta(max_length=64 * 1024)]
Bytes32 = Annotated[bytes, msgspec.Meta(min_length=32, max_length=32)]
Bytes64 = Annotated[bytes, msgspec.Meta(min_length=64, max_length=64)]
NonNegInt = Annotated[int, msgspec.Meta(ge=0)]
Seconds = Annotated[float, msgspec.Meta(ge=0.0)]


class MessageError(ValueError):
    """A payload is not a valid message of the expected type."""


class Message(msgspec.Struct, tag=True, tag_field="type", kw_only=True, frozen=True):
    """Base of every wire type.

    ``v`` is the schema version the sender wrote. A type that changes its
    schema raises the default of ``v`` in its own declaration; a decoder
    refuses versions newer than its own, and stays able to read older ones.

    Each subclass says ``frozen=True`` again: msgspec inherits it, but mypy's
    dataclass model of a Struct does not, and reads every subclass as a
    mutable dataclass deriving from a frozen one (an error per class).
    """

    v: int = 1


M = TypeVar("M", bound=Message)
# The other members of a tuple of expected types (decode's overloads).
M2 = TypeVar("M2", bound=Message)
M3 = TypeVar("M3", bound=Message)
M4 = TypeVar("M4", bound=Message)
M5 = TypeVar("M5", bound=Message)

Expected = type[Message] | tuple[type[Message], ...]
"""What :func:`decode` accepts: one message type or a tuple of them."""

_encoder = msgspec.msgpack.Encoder()


def encode(message: Message) -> bytes:
    """The MessagePack bytes of a message."""
    return _encoder.encode(message)


@functools.cache
def _decoder(expected: Any) -> msgspec.msgpack.Decoder[Any]:
    """The decoder of one type or of a tuple of types (cached by it: building a
    ``Union`` on every call cost more than decoding a small message)."""
    target: Any = Union[expected] if isinstance(expected, tuple) else expected  # noqa: UP007
    return msgspec.msgpack.Decoder(target)


@functools.cache
def _current_version(cls: type[Message]) -> int:
    for field in msgspec.structs.fields(cls):
        if field.name == "v":
            return int(field.default)
    return 1


def _payload_bytes(data: Any) -> bytes:
    if isinstance(data, bytes | bytearray | memoryview):
        return bytes(data)
    to_bytes = getattr(data, "to_bytes", None)  # zenoh.ZBytes
    if to_bytes is not None:
        return bytes(to_bytes())
    raise MessageError(f"cannot decode a payload of type {type(data).__name__}")


def _type_names(expected: type[Message] | tuple[type[Message], ...]) -> str:
    if isinstance(expected, tuple):
        return " or ".join(t.__name__ for t in expected)
    return expected.__name__


# Overloads per tuple length, so that a decode of (A, B) is typed A | B and each
# isinstance test narrows it (one typed Message would need a cast per use).
@overload
def decode(data: Any, expected: type[M]) -> M: ...
@overload
def decode(data: Any, expected: tuple[type[M]]) -> M: ...
@overload
def decode(data: Any, expected: tuple[type[M], type[M2]]) -> M | M2: ...
@overload
def decode(data: Any, expected: tuple[type[M], type[M2], type[M3]]) -> M | M2 | M3: ...
@overload
def decode(
    data: Any, expected: tuple[type[M], type[M2], type[M3], type[M4]]
) -> M | M2 | M3 | M4: ...
@overload
def decode(
    data: Any, expected: tuple[type[M], type[M2], type[M3], type[M4], type[M5]]
) -> M | M2 | M3 | M4 | M5: ...
@overload
def decode(data: Any, expected: tuple[type[Message], ...]) -> Message: ...
def decode(data: Any, expected: Expected) -> Message:
    """Decode and validate ``data`` as one of the ``expected`` message types.

    Raises :class:`MessageError` with a message that names the expected type
    and what was wrong (the field path, the bad value's type).
    """
    raw = data if type(data) is bytes else _payload_bytes(data)  # bytes: the usual case
    if len(raw) > MAX_MESSAGE_BYTES:
        raise MessageError(
            f"a {_type_names(expected)} message of {len(raw)} bytes is over the "
            f"{MAX_MESSAGE_BYTES}-byte limit"
        )
    try:
        message: Message = _decoder(expected).decode(raw)
    except msgspec.ValidationError as exc:
        raise MessageError(f"not a valid {_type_names(expected)} message: {exc}") from None
    except msgspec.DecodeError as exc:
        raise MessageError(
            f"not a valid {_type_names(expected)} message: malformed MessagePack ({exc})"
        ) from None
    if message.v == 1:  # every type starts at 1, so 1 is always readable
        return message
    newest = _current_version(type(message))
    if not 1 <= message.v <= newest:
        raise MessageError(
            f"{type(message).__name__} schema version {message.v} is not supported "
            f"(this program reads versions 1 to {newest}); upgrade this program"
        )
    return message


def all_message_types() -> list[type[Message]]:
    """Every concrete message type declared in common.messages."""
    found: list[type[Message]] = []
    pending: list[type[Message]] = list(Message.__subclasses__())
    while pending:
        cls = pending.pop()
        found.append(cls)
        pending.extend(cls.__subclasses__())
    return sorted(set(found), key=lambda t: t.__name__)


# --- replies shared by every queryable ------------------------------------------

ErrorCode = Literal[
    "bad_request",  # the payload did not decode or failed validation
    "unauthenticated",  # no valid session: missing, forged, expired, revoked or replayed
    "forbidden",  # a valid session without the permission
    "not_found",  # the room, agent, world or user does not exist
    "conflict",  # the request contradicts the current state (name taken, overlap)
    "rate_limited",  # too many requests or failed logins: retry later
    "unavailable",  # a service this one depends on did not answer
    "internal",  # a bug: the service logged it and kept serving
]


class ErrorReply(Message, frozen=True):
    """The answer of any queryable that refused or failed a request."""

    code: ErrorCode
    message: Text
    retry_after: float = 0.0


class OkReply(Message, frozen=True):
    """A request that has nothing to return succeeded."""

    detail: ShortText = ""


# --- bulk arrays ------------------------------------------------------------------

ArrayDType = Literal["float32", "float64", "int32", "uint8", "uint16", "int64"]


class PackedArray(msgspec.Struct, frozen=True, kw_only=True):
    """A numpy array as raw little-endian bytes (bulk data: poses, sensor values).

    Not a message by itself; a field of messages. ``to_numpy`` checks that the
    byte length matches dtype and shape, so a truncated array is an error.
    """

    dtype: ArrayDType
    shape: Annotated[list[Annotated[int, msgspec.Meta(ge=0)]], msgspec.Meta(max_length=4)]
    data: bytes

    @classmethod
    def from_numpy(cls, array: np.ndarray) -> PackedArray:
        dtype = array.dtype.newbyteorder("<")
        name = dtype.name
        if name not in ArrayDType.__args__:  # type: ignore[attr-defined]
            raise MessageError(f"arrays of {name} cannot be sent")
        contiguous = np.ascontiguousarray(array, dtype=dtype)
        return cls(
            dtype=cast(ArrayDType, name), shape=list(contiguous.shape), data=contiguous.tobytes()
        )

    def to_numpy(self) -> np.ndarray:
        dtype = np.dtype(self.dtype).newbyteorder("<")
        count = 1
        for dim in self.shape:
            count *= dim
        if count * dtype.itemsize != len(self.data):
            raise MessageError(
                f"array of shape {self.shape} and type {self.dtype} needs "
                f"{count * dtype.itemsize} bytes, got {len(self.data)}"
            )
        return np.frombuffer(self.data, dtype=dtype).reshape(self.shape)
