"""Operator accounts and their roles (``users`` table; docs/plant-integration.md, "Operators
and roles").

Three roles, each allowed what the one before it may do and more:

* ``viewer``: look (console pages, OPC UA reads and subscriptions, ``alarms list``, ``audit``);
* ``operator``: run nights and campaigns, move and park heliostats, switch lamps, acknowledge
  and shelve alarms;
* ``engineer``: change the configuration and the models, manage accounts.

Passwords are stored as scrypt hashes (RFC 7914, :func:`hashlib.scrypt`, N=2^14, r=8, p=1, a
16-byte random salt) in the form ``scrypt$N$r$p$<salt b64>$<hash b64>`` and compared in
constant time. The console's old shared token stays for scripts as the service account
:data:`SERVICE_ACCOUNT` (role engineer: what the token always could).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
import secrets
from dataclasses import dataclass

from controller.alarms.states import now_utc
from controller.errors import InputError
from controller.storage.audit import insert_audit
from controller.storage.checks import RecordError
from controller.storage.db import CampaignStore

ROLES = ("viewer", "operator", "engineer")
SERVICE_ACCOUNT = "service"  # the console token's account (role engineer)
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}$")
MIN_PASSWORD = 8
MAX_PASSWORD = 1024
SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**14, 8, 1


class AccessDenied(InputError):
    """The caller's role does not allow the action: HTTP 403, OPC UA BadUserAccessDenied."""


def allows(role: str, needed: str) -> bool:
    """Whether ``role`` may do what ``needed`` may (roles are ordered, :data:`ROLES`)."""
    return role in ROLES and ROLES.index(role) >= ROLES.index(needed)


def require(user: str, role: str, needed: str, what: str) -> None:
    """AccessDenied naming ``user``, its role and ``what`` unless ``role`` allows ``needed``."""
    if not allows(role, needed):
        raise AccessDenied(f"{user} ({role}) may not {what}: it needs the {needed} role")


def hash_password(password: str, salt: bytes | None = None) -> str:
    salt = salt or secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P, dklen=32)
    b64 = base64.b64encode
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${b64(salt).decode()}${b64(digest).decode()}"


def verify_password(stored: str, password: str) -> bool:
    """Whether ``password`` matches the ``stored`` hash (constant-time comparison)."""
    try:
        kind, n, r, p, salt, digest = stored.split("$")
        if kind != "scrypt":
            return False
        got = hashlib.scrypt(password.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r), p=int(p),
                             dklen=len(base64.b64decode(digest)))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, base64.b64decode(digest))


def check_password(password: str, source: str) -> str:
    """``password`` when it is printable text of :data:`MIN_PASSWORD` to :data:`MAX_PASSWORD`
    characters; InputError naming ``source`` otherwise (a binary file is no password file)."""
    if not MIN_PASSWORD <= len(password) <= MAX_PASSWORD:
        raise InputError(f"{source}: the password must have {MIN_PASSWORD} to {MAX_PASSWORD} characters")
    if not password.isprintable():
        raise InputError(f"{source}: the password must be printable text (no control characters)")
    return password


@dataclass(frozen=True)
class Account:
    name: str
    role: str
    created_utc: str

    def to_json(self) -> dict:
        return {"name": self.name, "role": self.role, "created_utc": self.created_utc}


class Accounts:
    """The accounts of ``store``."""

    def __init__(self, store: CampaignStore) -> None:
        self.store = store

    def add(self, name: str, role: str, password: str, *, by: str) -> Account:
        """A new account (audited as done ``by``); InputError for a bad name or role, or a name
        that exists."""
        if not NAME.match(name) or name == SERVICE_ACCOUNT:
            raise InputError(f"user name {name!r}: 1-64 letters, digits, _ . @ - (starting with a letter or "
                             f"digit), not {SERVICE_ACCOUNT!r}")
        if role not in ROLES:
            raise InputError(f"--role {role!r}: one of {', '.join(ROLES)}")
        stamp = now_utc().isoformat(timespec="milliseconds")
        with self.store.tx() as db:
            if db.execute("SELECT 1 FROM users WHERE name=?", (name,)).fetchone():
                raise InputError(f"{self.store.path}: user {name!r} exists (remove it first)")
            db.execute("INSERT INTO users (name, role, password_hash, created_utc) VALUES (?,?,?,?)",
                       (name, role, hash_password(password), stamp))
            insert_audit(db, by, "user.add", name, f"role {role}")
        return Account(name, role, stamp)

    def remove(self, name: str, *, by: str) -> None:
        with self.store.tx() as db:
            if db.execute("DELETE FROM users WHERE name=?", (name,)).rowcount == 0:
                raise InputError(f"{self.store.path}: no user {name!r} (see heliocal users list)")
            insert_audit(db, by, "user.remove", name, "")

    def list(self) -> list[Account]:
        rows = self.store.query("SELECT name, role, created_utc FROM users ORDER BY name")
        for r in rows:
            if r["role"] not in ROLES:
                raise RecordError(f"{self.store.path}: table users: {r['name']!r} has unknown role "
                                  f"{r['role']!r}")
        return [Account(r["name"], r["role"], r["created_utc"]) for r in rows]

    def any(self) -> bool:
        return bool(self.store.query("SELECT 1 FROM users LIMIT 1"))

    def check(self, name: str, password: str) -> Account | None:
        """The account when ``password`` is its password, else None (an unknown name costs the
        same hash, so timing does not tell which names exist)."""
        rows = self.store.query("SELECT * FROM users WHERE name=?", (name,))
        stored = rows[0]["password_hash"] if rows else hash_password("x" * MIN_PASSWORD, b"0" * 16)
        ok = verify_password(stored, password)
        if not rows or not ok or rows[0]["role"] not in ROLES:
            return None
        return Account(rows[0]["name"], rows[0]["role"], rows[0]["created_utc"])
