"""End-to-end encrypted private messages: sealing one for a recipient, opening one.

A message is encrypted (NaCl Box) to one of the recipient's keys: a live
session's box key, or their long-term mailbox key when offline, which a
password user derives from the password (argon2id) so nothing is stored.
The registry and the routers only ever carry ciphertext.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import nacl.exceptions
import nacl.public
import nacl.pwhash

from common import acl
from common.auth import Session
from common.messages import PrivateMessage

log = logging.getLogger("wart.client")


@dataclass(frozen=True)
class PrivateText:
    sender: str
    text: str
    sent_at: float
    kept: bool  # it waited in the mailbox while we were offline


def mailbox_key_from_password(realm: str, user: str, password: str) -> nacl.public.PrivateKey:
    """A password user's long-term mailbox key: argon2id of the password, no storage needed."""
    seed = nacl.pwhash.argon2id.kdf(
        32,
        password.encode(),
        acl.mailbox_salt(realm, user),
        opslimit=nacl.pwhash.argon2id.OPSLIMIT_INTERACTIVE,
        memlimit=nacl.pwhash.argon2id.MEMLIMIT_INTERACTIVE,
    )
    return nacl.public.PrivateKey(seed)


def seal_private(session: Session, user: str, to_key: bytes, text: str) -> PrivateMessage:
    """``text`` from ``session``'s user to ``user``, readable only with ``to_key``'s secret."""
    box = nacl.public.Box(session.keys.box_key, nacl.public.PublicKey(to_key))
    return PrivateMessage(
        sender=session.user,
        recipient=user,
        sender_box_key=session.keys.box_public_key,
        to_key=to_key,
        ciphertext=bytes(box.encrypt(text.encode())),
        sent_at=time.time(),
    )


def open_private(
    session: Session,
    mailbox: nacl.public.PrivateKey | None,
    message: PrivateMessage,
    *,
    kept: bool,
) -> PrivateText | None:
    """The text, or None when it is for another of this user's sessions or does not open.

    ``mailbox`` None: a session that has no mailbox key (yet): a resumed login, or one
    whose key is still being derived; messages to the session's own key still open.
    """
    if message.to_key == session.keys.box_public_key:
        mine = session.keys.box_key
    elif mailbox is not None and message.to_key == bytes(mailbox.public_key):
        mine = mailbox
    else:
        return None
    try:
        box = nacl.public.Box(mine, nacl.public.PublicKey(message.sender_box_key))
        text = box.decrypt(message.ciphertext).decode("utf-8")
    except (nacl.exceptions.CryptoError, UnicodeDecodeError):
        log.warning("could not decrypt a private message from %s", message.sender)
        return None
    return PrivateText(sender=message.sender, text=text, sent_at=message.sent_at, kept=kept)
