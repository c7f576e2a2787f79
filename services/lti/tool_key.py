"""The tool's own RSA key: it signs the client assertions of grade passback (AGS).

Made once, the first time the service starts, into the lab's state directory
(mode 0600); the platform learns its public half from the tool's JWKS URL
(``/lti/jwks``), so the key can be replaced by deleting the file: the LMS
fetches the new key set by itself.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from jwt.algorithms import RSAAlgorithm
from jwt.utils import base64url_encode


@dataclass(frozen=True)
class ToolKey:
    private: rsa.RSAPrivateKey
    kid: str

    def jwk(self) -> dict[str, Any]:
        public = json.loads(RSAAlgorithm.to_jwk(self.private.public_key()))
        public.pop("key_ops", None)  # "use" says it; RFC 7517 advises against both
        return {**public, "kid": self.kid, "alg": "RS256", "use": "sig"}

    def jwks(self) -> dict[str, Any]:
        return {"keys": [self.jwk()]}


def _kid(key: rsa.RSAPrivateKey) -> str:
    """The RFC 7638 thumbprint of the public key: a kid that changes with the key."""
    n = key.public_key().public_numbers()
    members = {
        "e": base64url_encode(n.e.to_bytes((n.e.bit_length() + 7) // 8, "big")).decode(),
        "kty": "RSA",
        "n": base64url_encode(n.n.to_bytes((n.n.bit_length() + 7) // 8, "big")).decode(),
    }
    canonical = json.dumps(members, separators=(",", ":"), sort_keys=True).encode()
    return base64url_encode(hashlib.sha256(canonical).digest()).decode()


def load_or_create(path: Path) -> tuple[ToolKey, bool]:
    """(the key, made now); a file that is not a key is an error, never overwritten."""
    if path.exists():
        try:
            key = serialization.load_pem_private_key(path.read_bytes(), password=None)
        except (OSError, ValueError, TypeError) as exc:
            raise ValueError(f"{path}: not the tool's RSA key ({exc}); move it away") from None
        if not isinstance(key, rsa.RSAPrivateKey):
            raise ValueError(f"{path}: not an RSA key")
        if os.stat(path).st_mode & 0o077:
            path.chmod(0o600)
        return ToolKey(key, _kid(key)), False
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    # Made 0600 from its first byte (a temporary file with the umask's mode would not be).
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as out:
        out.write(pem)
        out.flush()
        os.fsync(out.fileno())
    return ToolKey(key, _kid(key)), True
