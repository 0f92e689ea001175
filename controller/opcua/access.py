"""Who calls: the ``users`` accounts as OPC UA username/password identities, and the caller of
each method (docs/plant-integration.md, "OPC UA", "Operators and roles").

asyncua checks every request against the session's user before serving it
(:class:`Callers`, its permission ruleset) and runs a method's coroutine in the same task
right after; the ruleset notes the user in a context variable the method reads. Anonymous
sessions are refused; a method whose caller's role is too low answers ``BadUserAccessDenied``
and the refusal is audited.
"""

from __future__ import annotations

import contextvars
from dataclasses import dataclass

from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.user_managers import UserManager

from controller.storage.users import Accounts

CALLER: contextvars.ContextVar[User | None] = contextvars.ContextVar("heliocal_opcua_caller", default=None)


@dataclass
class Operator(User):
    """An asyncua session user with its heliocal role."""

    heliocal_role: str = "viewer"


class AccountUsers(UserManager):
    """Username/password identities checked against the accounts (scrypt)."""

    def __init__(self, accounts: Accounts) -> None:
        self.accounts = accounts

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if not username or password is None:
            return None
        acc = self.accounts.check(username, password)
        if acc is None:
            return None
        return Operator(role=UserRole.User, name=acc.name, heliocal_role=acc.role)


class Callers:
    """asyncua's permission ruleset: every request of a signed-in account passes (the methods
    check roles themselves, and writes are refused to every client by asyncua), anything else
    is refused; the request's user is noted for the method it may call."""

    def check_validity(self, user, action_type_id, body) -> bool:
        CALLER.set(user)
        return isinstance(user, Operator)


def caller() -> Operator | None:
    user = CALLER.get()
    return user if isinstance(user, Operator) else None
