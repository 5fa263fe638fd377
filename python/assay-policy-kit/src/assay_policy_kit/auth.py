"""The cluster token, as Assay's policy and world-model clients present it.

A cluster with a token (`$ASSAY_CLUSTER_TOKEN`, or the file `$ASSAY_CLUSTER_TOKEN_FILE` names)
sends every policy call with `authorization: Bearer <hex SHA-256 of b"assay/policy\\0" + token>`,
and every world-model call with the same of b"assay/world-model\\0" + token: a server never sees
the cluster token itself, nor another service's secret.
"""

from __future__ import annotations

import hashlib
import hmac
import os
from typing import Optional

TOKEN_ENV = "ASSAY_CLUSTER_TOKEN"
TOKEN_FILE_ENV = "ASSAY_CLUSTER_TOKEN_FILE"
MIN_TOKEN_LEN = 16


def check_token(text: str) -> str:
    t = text.strip()
    if len(t) < MIN_TOKEN_LEN:
        raise ValueError(f"the cluster token has {len(t)} characters; it needs at least {MIN_TOKEN_LEN}")
    if not all(33 <= ord(c) <= 126 for c in t):
        raise ValueError("the cluster token must be printable ASCII without spaces")
    return t


def token_from_env() -> Optional[str]:
    """The cluster token, or None when neither variable is set (then every call is accepted)."""
    if TOKEN_ENV in os.environ:
        try:
            return check_token(os.environ[TOKEN_ENV])
        except ValueError as e:
            raise ValueError(f"${TOKEN_ENV}: {e}") from None
    path = os.environ.get(TOKEN_FILE_ENV)
    if path is not None:
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except OSError as e:
            raise ValueError(f"${TOKEN_FILE_ENV} names {path}, which cannot be read: {e}") from None
        try:
            return check_token(text)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
    return None


POLICY = "policy"
WORLD_MODEL = "world-model"


def service_secret(token: str, service: str) -> str:
    """The secret a server of `service` checks: hex SHA-256 of b"assay/<service>\\0" + token
    (Assay's `Token::derive`)."""
    return hashlib.sha256(b"assay/" + service.encode() + b"\0" + token.encode()).hexdigest()


def policy_secret(token: str) -> str:
    """The secret a policy server checks: hex SHA-256 of b"assay/policy\\0" + token."""
    return service_secret(token, POLICY)


def bearer(token: str, service: str = POLICY) -> str:
    """The `authorization` metadata value a client sends to a server of `service`."""
    return "Bearer " + service_secret(token, service)


def matches(expected: str, presented: Optional[str]) -> bool:
    if presented is None:
        return False
    return hmac.compare_digest(expected.encode(), presented.encode())
