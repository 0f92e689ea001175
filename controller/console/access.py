"""Who acts on the console (docs/console.md, "Accounts"; docs/plant-integration.md).

* With operator accounts in the database (``heliocal users``), a state-changing request needs
  a signed-in account: ``POST /api/login`` with ``{"user", "password"}`` returns a session
  token, which the page sends as ``X-Heliocal-Token``. A session lasts :data:`SESSION_S`.
* The console's own ``--token`` stays for scripts: the service account ``service``, with the
  rights the token always had (role engineer).
* Without accounts and without a token (a console on this machine only, as before accounts
  existed) requests act as ``local``, with the rights they always had (role engineer).

Each request's account and role decide what it may do (:func:`controller.storage.users.require`);
every action is audited with its name.
"""

from __future__ import annotations

import hmac
import secrets
import threading
import time
from dataclasses import dataclass

from controller.storage.db import CampaignStore
from controller.storage.users import SERVICE_ACCOUNT, Accounts

SESSION_S = 12 * 3600.0
LOCAL_ACCOUNT = "local"


@dataclass(frozen=True)
class Who:
    name: str
    role: str


class ConsoleAccess:
    """Sessions of the console over ``store``'s accounts; ``token``: the service account's."""

    def __init__(self, store: CampaignStore, token: str | None) -> None:
        self.accounts = Accounts(store)
        self.token = token
        self._sessions: dict[str, tuple[Who, float]] = {}
        self._lock = threading.Lock()

    def login(self, name: str, password: str) -> tuple[str, Who] | None:
        acc = self.accounts.check(name, password)
        if acc is None:
            return None
        token = secrets.token_urlsafe(24)
        who = Who(acc.name, acc.role)
        with self._lock:
            now = time.monotonic()
            self._sessions = {k: v for k, v in self._sessions.items() if v[1] > now}
            self._sessions[token] = (who, now + SESSION_S)
        return token, who

    def logout(self, sent: str) -> None:
        with self._lock:
            self._sessions.pop(sent, None)

    def accounts_exist(self) -> bool:
        return self.accounts.any()

    def who(self, sent: str) -> Who | None:
        """The account a request's ``X-Heliocal-Token`` stands for, or None (401)."""
        if self.token is not None and sent and hmac.compare_digest(sent.encode(), self.token.encode()):
            return Who(SERVICE_ACCOUNT, "engineer")
        with self._lock:
            hit = self._sessions.get(sent) if sent else None
            if hit is not None and hit[1] > time.monotonic():
                return hit[0]
        if self.token is None and not self.accounts_exist():
            return Who(LOCAL_ACCOUNT, "engineer")
        return None
