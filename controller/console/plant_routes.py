"""The console's plant-integration pages and API: the alarm list with its banner, the audit
trail, signing in (docs/console.md; docs/plant-integration.md).

* ``GET /alarms``, ``/audit``, ``/login``: the pages; ``GET /api/alarms`` the list and the
  latest history, ``POST /api/alarms/{id}/ack|shelve|unshelve`` (operator; ``{"comment"}``,
  shelve ``{"for": "2h"}``);
* ``GET /api/audit?since=ISO`` the audit trail; ``POST /api/login`` ``{"user", "password"}`` →
  ``{"token"}``, ``POST /api/logout``, ``GET /api/whoami``;
* ``alarms`` and ``model`` server-sent events when the store's alarm history or models change
  (whichever process changed them: a CLI night, the OPC UA server), read every
  :data:`WATCH_S`.
"""

from __future__ import annotations

import json
import threading

from starlette.requests import Request
from starlette.routing import Route

from controller.alarms.states import now_utc, parse_duration
from controller.console.access import ConsoleAccess
from controller.console.backend import Console, only_keys
from controller.errors import InputError
from controller.storage.alarms import AlarmBook
from controller.storage.audit import AuditTrail, audit_entries, parse_since

WATCH_S = 1.0
HISTORY = 50
# Actions the orchestration audits itself (the night's start and end, the alarm book's changes).
SELF_AUDITED = ("/api/night/start", "/api/campaign/start", "/api/alarms/", "/api/login", "/api/logout")


def audited(request: Request, body: dict, out, store) -> None:
    """Record a console request that changed something, as its account."""
    path = request.url.path
    if any(path.startswith(p) for p in SELF_AUDITED):
        return
    p = request.path_params
    if "step" in p:
        action, target = f"heliostat.{p['step']}", p["hid"]
    elif path.startswith("/api/campaign/"):
        action, target = f"campaign.{p['action']}", (out or {}).get("name") or ""
    elif path.startswith("/api/night/"):
        action, target = f"night.{p['action']}", (out or {}).get("name") or ""
    else:
        action, target = path, ""
    AuditTrail(store, request.state.who.name).record(action, target, json.dumps(body) if body else "")


def plant_routes(c: Console, access: ConsoleAccess, post, get, page) -> list[Route]:
    book = AlarmBook(c.store)
    _watch(c, book)

    def api_alarms(request):
        now = now_utc()
        return {"alarms": [a.to_json(now) for a in book.alarms(include_normal="all" in request.query_params)],
                "history": book.events(max(0, book.last_event_id() - HISTORY))}

    def api_alarm_action(request, body):
        aid, action, who = request.path_params["aid"], request.path_params["action"], request.state.who
        only_keys(body, ("comment", "for"), f"alarm {action}")
        comment = body.get("comment") or ""
        if not isinstance(comment, str):
            raise InputError("comment must be text")
        if action == "ack":
            a = book.acknowledge(aid, who.name, comment)
        elif action == "shelve":
            a = book.shelve(aid, who.name, parse_duration(str(body.get("for") or ""), "for"), comment)
        elif action == "unshelve":
            a = book.unshelve(aid, who.name)
        else:
            raise InputError(f"unknown alarm action {action!r}; one of ack, shelve, unshelve")
        c.bus.publish("alarms", {"changed": aid})
        return {"ok": True, "alarm": a.to_json(now_utc())}

    def api_audit(request):
        since = parse_since(request.query_params.get("since"))
        return {"audit": audit_entries(c.store, since, limit=None if since else 500)}

    def api_login(request, body):
        only_keys(body, ("user", "password"), "login")
        name, password = body.get("user"), body.get("password")
        if not isinstance(name, str) or not isinstance(password, str):
            raise InputError("send {\"user\": NAME, \"password\": PASSWORD}")
        got = access.login(name, password)
        if got is None:
            raise _BadLogin("unknown user or wrong password")
        token, who = got
        return {"ok": True, "token": token, "user": who.name, "role": who.role}

    def api_logout(request, body):
        only_keys(body, (), "logout")
        access.logout(request.headers.get("X-Heliocal-Token", ""))
        return {"ok": True}

    def api_whoami(request):
        who = access.who(request.headers.get("X-Heliocal-Token", ""))
        return {"user": who.name if who else None, "role": who.role if who else None,
                "accounts": access.accounts_exist()}

    return [
        *[Route(f"/{p}", page(p)) for p in ("alarms", "audit", "login")],
        Route("/api/alarms", get(api_alarms)),
        Route("/api/alarms/{aid:int}/{action}", post(api_alarm_action), methods=["POST"]),
        Route("/api/audit", get(api_audit)),
        Route("/api/login", post(api_login, needed=None, signed_in=False), methods=["POST"]),
        Route("/api/logout", post(api_logout, needed=None), methods=["POST"]),
        Route("/api/whoami", get(api_whoami)),
    ]


class _BadLogin(InputError):
    """A sign-in that failed (answered 400 without saying which part was wrong)."""


def _watch(c: Console, book: AlarmBook) -> None:
    """Publish ``alarms`` / ``model`` events when the store's alarm history or models change."""
    def loop() -> None:
        seen = (book.last_event_id(), _last_model(c))
        while not c.closing.wait(WATCH_S):
            try:
                now = (book.last_event_id(), _last_model(c))
            except Exception:  # a store being closed at shutdown
                return
            if now[0] != seen[0]:
                c.bus.publish("alarms", {"last_event": now[0]})
            if now[1] != seen[1]:
                row = c.store.query("SELECT heliostat_id FROM model_params WHERE id=?", (now[1],))
                c.bus.publish("model", {"model_id": now[1], "heliostat": row[0][0] if row else None})
            seen = now
    threading.Thread(target=loop, name="console-alarm-watch", daemon=True).start()


def _last_model(c: Console) -> int:
    return int(c.store.query("SELECT COALESCE(MAX(id), 0) FROM model_params")[0][0])
