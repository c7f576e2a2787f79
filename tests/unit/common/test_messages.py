"""Every message type round-trips; malformed or hostile payloads give one clear error."""

from __future__ import annotations

import enum
import re
import typing

import msgpack
import msgspec
import numpy as np
import pytest

import common.messages as messages
from common.messages import (
    ErrorReply,
    Message,
    MessageError,
    OkReply,
    PackedArray,
    all_message_types,
    decode,
    encode,
)


def sample_value(tp: object, name: str = "") -> object:
    """A valid value for a field type, honouring msgspec constraints."""
    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        base, *metas = typing.get_args(tp)
        meta = next((m for m in metas if isinstance(m, msgspec.Meta)), None)
        if meta is not None and base is bytes and meta.min_length:
            return b"\x01" * meta.min_length
        if meta is not None and base is str and meta.pattern:
            # the first of these the pattern takes (a part name is an identifier: no "-")
            return next(c for c in ("name-1.py", "name-1", "name_1") if re.match(meta.pattern, c))
        if meta is not None and base in (int, float) and meta.ge is not None:
            return base(meta.ge) + base(1)
        return sample_value(base, name)
    if origin is typing.Literal:
        return typing.get_args(tp)[0]
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return (sample_value(args[0], name),)
        return tuple(sample_value(arg, name) for arg in args)
    if origin in (list, set, frozenset):
        args = typing.get_args(tp)
        return [sample_value(args[0], name)] if args else []
    if origin is dict:
        key, value = typing.get_args(tp)
        return {sample_value(key): sample_value(value)}
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return sample_value(typing.get_args(tp)[0], name)
    if isinstance(tp, type):
        if issubclass(tp, bool):
            return True
        if issubclass(tp, enum.Enum):
            return next(iter(tp))
        if issubclass(tp, int):
            return 3
        if issubclass(tp, float):
            return 1.5
        if issubclass(tp, str):
            return "text"
        if issubclass(tp, bytes):
            return b"\x00\x01"
        if tp is msgspec.Raw:  # an embedded, still-encoded message
            return msgspec.Raw(msgspec.msgpack.encode({"embedded": 1}))
        if tp is PackedArray:
            return PackedArray.from_numpy(np.arange(6, dtype=np.float32).reshape(2, 3))
        if issubclass(tp, msgspec.Struct):
            return build(tp)
    if tp is typing.Any:
        return None
    raise NotImplementedError(f"no sample for {tp!r} ({name})")


def build(cls: type) -> object:
    hints = typing.get_type_hints(cls, include_extras=True)
    values = {}
    for field in msgspec.structs.fields(cls):
        if field.name == "v":
            continue
        values[field.name] = sample_value(hints[field.name], f"{cls.__name__}.{field.name}")
    return cls(**values)


TYPES = all_message_types()


def test_every_type_is_exported_and_named_uniquely() -> None:
    names = [t.__name__ for t in TYPES]
    assert len(names) == len(set(names))
    for t in TYPES:
        assert getattr(messages, t.__name__, None) is t, f"{t.__name__} not in common.messages"


@pytest.mark.parametrize("cls", TYPES, ids=[t.__name__ for t in TYPES])
def test_round_trip(cls: type[Message]) -> None:
    original = build(cls)
    data = encode(original)
    assert decode(data, cls) == original
    # The wire format is plain MessagePack, tagged with the type's name and version.
    raw = msgpack.unpackb(data, raw=False)
    assert raw["type"] == cls.__name__ and raw["v"] >= 1


def test_wrong_field_type_names_the_field() -> None:
    data = msgpack.packb({"type": "ErrorReply", "code": "internal", "message": 42})
    with pytest.raises(MessageError, match=r"ErrorReply.*\$\.message"):
        decode(data, ErrorReply)


def test_malformed_msgpack_is_a_message_error() -> None:
    with pytest.raises(MessageError, match="malformed MessagePack"):
        decode(b"\xc1\xff\x00", OkReply)


def test_unexpected_type_is_refused() -> None:
    with pytest.raises(MessageError, match="not a valid OkReply"):
        decode(encode(ErrorReply(code="internal", message="x")), OkReply)


def test_union_decodes_the_right_type() -> None:
    reply = decode(encode(OkReply(detail="d")), (OkReply, ErrorReply))
    assert reply == OkReply(detail="d")


def test_newer_schema_version_is_refused_clearly() -> None:
    data = msgpack.packb({"type": "OkReply", "v": 99, "detail": ""})
    with pytest.raises(MessageError, match="version 99 is not supported"):
        decode(data, OkReply)


def test_constraint_violation_is_refused() -> None:
    data = msgpack.packb({"type": "ErrorReply", "code": "no-such-code", "message": "x"})
    with pytest.raises(MessageError):
        decode(data, ErrorReply)


def test_oversized_payload_is_refused_before_decoding() -> None:
    with pytest.raises(MessageError, match="over the"):
        decode(b"\x00" * (messages.MAX_MESSAGE_BYTES + 1), OkReply)


def test_packed_array_round_trip_and_length_check() -> None:
    poses = np.random.default_rng(1).normal(size=(1000, 3)).astype(np.float32)
    packed = PackedArray.from_numpy(poses)
    assert np.array_equal(packed.to_numpy(), poses)
    truncated = PackedArray(dtype="float32", shape=[1000, 3], data=packed.data[:-4])
    with pytest.raises(MessageError, match="needs 12000 bytes"):
        truncated.to_numpy()
