"""The authenticated envelope: what a service accepts and what it refuses."""

from __future__ import annotations

import pytest

from common.auth import AuthError, RegistryIdentity, Verifier, issue_session, key_fingerprint
from common.messages import OkReply, encode
from common.messages.auth import AuthEnvelope

REALM = "lab"
KEY = "wart/lab/ctx/room/in"


@pytest.fixture
def identity() -> RegistryIdentity:
    return RegistryIdentity.generate()


def test_valid_message_opens_with_its_sender(identity: RegistryIdentity) -> None:
    session = issue_session(identity, REALM, "alice", ["chat", "join"])
    verifier = Verifier(identity.verify_key, REALM)
    principal, message = verifier.open(KEY, session.seal(KEY, OkReply(detail="hi")), OkReply)
    assert principal.user == "alice" and principal.has("chat") and not principal.has("kick")
    assert message == OkReply(detail="hi")


def test_replay_is_refused(identity: RegistryIdentity) -> None:
    session = issue_session(identity, REALM, "alice", ["chat"])
    verifier = Verifier(identity.verify_key, REALM)
    payload = session.seal(KEY, OkReply())
    verifier.open(KEY, payload, OkReply)
    with pytest.raises(AuthError, match="replayed"):
        verifier.open(KEY, payload, OkReply)


def test_out_of_order_messages_are_each_accepted_once(identity: RegistryIdentity) -> None:
    session = issue_session(identity, REALM, "alice", ["chat"])
    verifier = Verifier(identity.verify_key, REALM)
    first, second = session.seal(KEY, OkReply()), session.seal(KEY, OkReply())
    verifier.open(KEY, second, OkReply)
    verifier.open(KEY, first, OkReply)
    with pytest.raises(AuthError):
        verifier.open(KEY, first, OkReply)


def test_message_moved_to_another_key_is_refused(identity: RegistryIdentity) -> None:
    session = issue_session(identity, REALM, "alice", ["chat"])
    verifier = Verifier(identity.verify_key, REALM)
    with pytest.raises(AuthError, match="signature"):
        verifier.open("wart/lab/ctx/other/in", session.seal(KEY, OkReply()), OkReply)


def test_token_from_another_registry_is_refused(identity: RegistryIdentity) -> None:
    impostor = RegistryIdentity.generate()
    session = issue_session(impostor, REALM, "admin", ["admin"])
    verifier = Verifier(identity.verify_key, REALM)
    with pytest.raises(AuthError, match="not signed by this lab's registry"):
        verifier.open(KEY, session.seal(KEY, OkReply()), OkReply)


def test_forged_body_is_refused(identity: RegistryIdentity) -> None:
    import msgspec

    from common.messages import decode

    session = issue_session(identity, REALM, "alice", ["chat"])
    envelope = decode(session.seal(KEY, OkReply(detail="a")), AuthEnvelope)
    forged = msgspec.structs.replace(envelope, body=encode(OkReply(detail="b")))
    with pytest.raises(AuthError, match="signature"):
        Verifier(identity.verify_key, REALM).open(KEY, encode(forged), OkReply)


def test_expired_and_revoked_sessions_are_refused(identity: RegistryIdentity) -> None:
    now = [1000.0]
    verifier = Verifier(identity.verify_key, REALM, clock=lambda: now[0])
    session = issue_session(identity, REALM, "alice", ["chat"], ttl=60, now=1000.0)
    verifier.open(KEY, session.seal(KEY, OkReply(), now=1000.0), OkReply)
    now[0] = 1061.0
    with pytest.raises(AuthError, match="expired"):
        verifier.open(KEY, session.seal(KEY, OkReply(), now=1061.0), OkReply)
    other = issue_session(identity, REALM, "bob", ["chat"], now=1061.0)
    verifier.revoke(other.session_id)
    with pytest.raises(AuthError, match="revoked"):
        verifier.open(KEY, other.seal(KEY, OkReply(), now=1061.0), OkReply)


def test_a_refused_message_names_its_signer_only_when_its_session_key_signed_it(
    identity: RegistryIdentity,
) -> None:
    import msgspec

    from common.messages import decode

    verifier = Verifier(identity.verify_key, REALM)
    bob = issue_session(identity, REALM, "bob", ["chat"])
    verifier.revoke(bob.session_id)
    sealed = bob.seal(KEY, OkReply(detail="after logout"))
    with pytest.raises(AuthError, match="revoked"):
        verifier.open(KEY, sealed, OkReply)
    assert verifier.signer_of(KEY, sealed) == "bob"
    # His token copied under a body he did not sign, moved to another key, or a token
    # of another registry, or no envelope at all: nobody is named.
    envelope = decode(sealed, AuthEnvelope)
    forged = encode(msgspec.structs.replace(envelope, body=encode(OkReply(detail="lie"))))
    assert verifier.signer_of(KEY, forged) is None
    assert verifier.signer_of("wart/lab/ctx/other/in", sealed) is None
    impostor = issue_session(RegistryIdentity.generate(), REALM, "admin", ["admin"])
    assert verifier.signer_of(KEY, impostor.seal(KEY, OkReply())) is None
    assert verifier.signer_of(KEY, b"\x93\x01\x02") is None


def test_stale_message_is_refused(identity: RegistryIdentity) -> None:
    verifier = Verifier(identity.verify_key, REALM, clock=lambda: 2000.0)
    session = issue_session(identity, REALM, "alice", ["chat"], now=1990.0)
    with pytest.raises(AuthError, match="clock"):
        verifier.open(KEY, session.seal(KEY, OkReply(), now=1960.0), OkReply)


def test_token_for_another_realm_is_refused(identity: RegistryIdentity) -> None:
    session = issue_session(identity, "otherlab", "alice", ["chat"])
    with pytest.raises(AuthError, match="realm"):
        Verifier(identity.verify_key, REALM).open(KEY, session.seal(KEY, OkReply()), OkReply)


def test_garbage_is_refused_as_unauthenticated(identity: RegistryIdentity) -> None:
    with pytest.raises(AuthError) as info:
        Verifier(identity.verify_key, REALM).open(KEY, b"\x93\x01\x02", OkReply)
    assert info.value.code == "unauthenticated"


def test_permission_check_names_the_permission(identity: RegistryIdentity) -> None:
    session = issue_session(identity, REALM, "bob", ["chat"])
    principal, _ = Verifier(identity.verify_key, REALM).open(
        KEY, session.seal(KEY, OkReply()), OkReply
    )
    with pytest.raises(AuthError, match="'kick' permission") as info:
        principal.require("kick", "remove users")
    assert info.value.code == "forbidden"


def test_fingerprint_is_stable_and_short(identity: RegistryIdentity) -> None:
    fp = key_fingerprint(identity.verify_key)
    assert fp == key_fingerprint(identity.verify_key) and len(fp) == 39


def test_cached_signature_does_not_vouch_for_other_token_bytes(identity: RegistryIdentity) -> None:
    import msgspec

    from common.messages import decode
    from common.messages.auth import SessionToken, SignedToken

    verifier = Verifier(identity.verify_key, REALM)
    session = issue_session(identity, REALM, "alice", ["chat"])
    verifier.verify_token(session.signed_token)  # now cached
    forged_token = msgspec.structs.replace(
        decode(session.signed_token.token, SessionToken), user="admin", permissions=["admin"]
    )
    forged = SignedToken(token=encode(forged_token), signature=session.signed_token.signature)
    with pytest.raises(AuthError, match="not signed by this lab's registry"):
        verifier.verify_token(forged)
