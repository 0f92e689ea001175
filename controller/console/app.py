"""The console's ASGI app (Starlette): pages, JSON API, server-sent events.

Security model (docs/console.md): nothing changes state on GET; every state-changing request
is a POST with a JSON body (``Content-Type: application/json``, so a form on another web site
cannot send one without a CORS preflight, which this app never grants) and, when it carries an
``Origin``, from this console's own origin. With a token (always when the console listens on an
address other than loopback) or operator accounts, every POST must carry ``X-Heliocal-Token``:
the token (the service account) or a signed-in account's session
(:mod:`controller.console.access`); otherwise 401 and nothing is done. The account's role must
allow the request (403 otherwise), and every state change is audited with its name.
"""

from __future__ import annotations

from pathlib import Path
from urllib.parse import urlsplit

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, RedirectResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from controller.calibration.cycle.beam_safety import UnsafePath
from controller.commands._id_lists import campaign_name
from controller.console import views
from controller.console.access import ConsoleAccess
from controller.console.backend import Conflict, Console, only_keys
from controller.console.campaigns import CampaignControl
from controller.console.events import plain
from controller.console.nights import NightControl
from controller.console.plant_routes import audited, plant_routes
from controller.console.steps import STEPS, run_step
from controller.devices.drive import DriveError, LinkError, NakError
from controller.errors import HeliocalError, InputError, LimitError
from controller.io.json_files import parse_json
from controller.io.text_numbers import is_ascii_index
from controller.storage.audit import AuditTrail
from controller.storage.lock import DatabaseBusy
from controller.storage.users import AccessDenied, require

STATIC = Path(__file__).resolve().parent / "static"
TOKEN_HEADER = "X-Heliocal-Token"
PAGES = ("field", "heliostat", "commission", "campaign", "reports")


def _json(data, status: int = 200) -> JSONResponse:
    return JSONResponse(plain(data), status_code=status)


def error_response(exc: HeliocalError) -> JSONResponse:
    """A controller error as JSON ``{"ok": false, "error", "kind", "outcome"}`` with its HTTP
    status: 400 bad input or soft limits (nothing sent), 409 conflicts (campaign running,
    target held, database in use, unsafe path) and firmware refusals (NAK), 502 device failures."""
    if isinstance(exc, AccessDenied):
        status, kind = 403, "forbidden"
    elif isinstance(exc, (Conflict, DatabaseBusy, UnsafePath)):
        status, kind = 409, "conflict"
    elif isinstance(exc, NakError):  # before LimitError: a Modbus out-of-range refusal is both
        status, kind = 409, "firmware_refused"
    elif isinstance(exc, LimitError):
        status, kind = 400, "soft_limits"  # the controller's own check: nothing was sent
    elif isinstance(exc, LinkError):
        status, kind = 502, "link"
    elif isinstance(exc, InputError):
        status, kind = 400, "input"
    elif isinstance(exc, DriveError):
        status, kind = 502, "drive"
    else:
        status, kind = 502, "device"
    return _json({"ok": False, "error": str(exc), "kind": kind, "outcome": exc.outcome}, status)


MAX_BODY_BYTES = 64 << 10  # a command to the console is a few hundred bytes
MAX_BODY_DEPTH = 8  # and nests two levels


async def _bounded_json(request: Request):
    """The request's JSON body, refused (413, 400) before parsing when it is too large, nested
    too deep, not UTF-8, not JSON or has a key twice — never a 500."""
    declared = request.headers.get("content-length", "")
    if not is_ascii_index(declared) or int(declared) > MAX_BODY_BYTES:
        raise _Refused(413, f"request body of {declared} bytes is too large (at most {MAX_BODY_BYTES})")
    data = bytearray()
    async for chunk in request.stream():
        data += chunk
        if len(data) > MAX_BODY_BYTES:
            raise _Refused(413, f"request body is too large (at most {MAX_BODY_BYTES} bytes)")
    try:
        return parse_json(data.decode("utf-8"), "the request body", MAX_BODY_DEPTH)
    except UnicodeDecodeError:
        raise _Refused(400, "the request body is not UTF-8 text") from None
    except InputError as exc:
        raise _Refused(400, str(exc)) from None


def create_app(console: Console, *, token: str | None = None) -> Starlette:
    """The app over ``console``. ``token``: required on every POST when given."""
    if console.campaign is None:
        console.campaign = CampaignControl(console)
    if console.night is None:
        console.night = NightControl(console)
    c = console
    access = ConsoleAccess(c.store, token)

    async def guard(request: Request, signed_in: bool = True) -> dict:
        """The checks of every state-changing request; returns its JSON body (the account in
        ``request.state.who``)."""
        if signed_in:
            who = await run_in_threadpool(access.who, request.headers.get(TOKEN_HEADER, ""))
            if who is None:
                raise _Refused(401, f"missing or wrong {TOKEN_HEADER} header: sign in, or send the console's "
                                    "token")
            request.state.who = who
        origin = request.headers.get("origin")
        if origin and urlsplit(origin).netloc != request.headers.get("host", ""):
            raise _Refused(403, f"cross-origin request from {origin} refused")
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            raise _Refused(415, "send the request body as application/json")
        body = await _bounded_json(request)
        if not isinstance(body, dict):
            raise _Refused(400, "the request body must be a JSON object")
        return body

    def post(handler, needed: str | None = "operator", signed_in: bool = True):
        """A POST endpoint: ``guard``, then the account's role must allow ``needed``, then the
        handler; its action is audited (:func:`controller.console.plant_routes.audited`)."""
        async def endpoint(request: Request) -> Response:
            try:
                body = await guard(request, signed_in)
            except _Refused as r:
                return _json({"ok": False, "error": r.message, "kind": "refused"}, r.status)

            def act():
                if needed is not None:
                    who = request.state.who
                    require(who.name, who.role, _needed(request, needed), request.url.path)
                out = handler(request, body)
                audited(request, body, out, c.store)
                return out
            try:
                return _json(await run_in_threadpool(act))
            except HeliocalError as exc:
                return error_response(exc)
        return endpoint

    def get(handler):
        async def endpoint(request: Request) -> Response:
            try:
                out = await run_in_threadpool(handler, request)
            except HeliocalError as exc:
                return error_response(exc)
            return out if isinstance(out, Response) else _json(out)
        return endpoint

    # -- pages ---------------------------------------------------------------------------------------
    def page(name: str):
        async def endpoint(request: Request) -> Response:
            return FileResponse(STATIC / f"{name}.html", headers={"Cache-Control": "no-store"})
        return endpoint

    # -- API -----------------------------------------------------------------------------------------
    def api_plant(request):
        return {**views.plant_json(c), "token_required": token is not None, "steps": list(STEPS),
                "accounts": access.accounts_exist()}

    def api_heliostats(request):
        return {"heliostats": views.heliostat_summaries(c, c.ids)}

    def api_heliostat(request):
        return views.heliostat_detail(c, c.known(request.path_params["hid"]))

    def api_image(request):
        png = views.overlay_png(c, c.known(request.path_params["hid"]))
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    def api_step(request, body):
        hid, step = request.path_params["hid"], request.path_params["step"]
        return {"ok": True, "heliostat": hid, "step": step, "result": run_step(c, c.known(hid), step, body)}

    def api_campaign(request):
        return c.campaign.snapshot()

    def api_campaign_action(request, body):
        action = request.path_params["action"]
        only_keys(body, ("name", "heliostats") if action == "start" else (), f"campaign {action}")
        if action == "start":
            from controller.commands.campaigns.campaign import default_name

            ids = c.heliostats_for("campaign", body.get("heliostats"))  # checked before anything changes
            name = body.get("name")
            if name is not None:
                name = campaign_name(name, "name")
            c.field.audit = AuditTrail(c.store, request.state.who.name)  # the runs' model changes
            return c.campaign.start(name or default_name(c.config_path), ids)
        if action in ("pause", "resume", "abort"):
            return getattr(c.campaign, action)()
        raise InputError(f"unknown campaign action {action!r}; one of start, pause, resume, abort")

    def api_night(request):
        return c.night.snapshot()

    def api_night_action(request, body):
        action = request.path_params["action"]
        only_keys(body, ("heliostats",) if action == "start" else (), f"night {action}")
        if action == "start":
            ids = c.heliostats_for("night", body.get("heliostats"))  # checked before anything changes
            c.field.audit = AuditTrail(c.store, request.state.who.name)  # the night's lamps, models, end
            return c.night.start(ids)
        if action == "stop":
            return c.night.stop()
        raise InputError(f"unknown night action {action!r}; one of start, stop")

    def api_reports(request):
        return {"nights": views.nights_json(c), "campaigns": views.campaigns_json(c),
                "confusion": views.confusion_reports(c)}

    def campaign_report(request):
        out = views.morning_report(c, int(request.path_params["cid"]))
        return FileResponse(views.report_file(out, request.path_params.get("file") or "report.html"))

    def night_report(request):
        out = views.night_report(c, int(request.path_params["idx"]))
        return FileResponse(views.report_file(out, request.path_params.get("file") or "report.html"))

    def report_files(request):
        if not c.reports_dir:
            raise InputError("the console was started without --reports DIR")
        return FileResponse(views.report_file(Path(c.reports_dir), request.path_params["file"]))

    async def events(request: Request) -> Response:
        return StreamingResponse(c.bus.stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def refuse_get(request: Request) -> Response:
        return _json({"ok": False, "error": "state changes need POST"}, 405)

    routes = [
        Route("/", lambda request: RedirectResponse("/field")),
        *[Route(f"/{p}", page(p)) for p in ("field", "campaign", "reports")],
        Route("/heliostat/{hid}", page("heliostat")),
        Route("/commission/{hid}", page("commission")),
        Route("/api/plant", get(api_plant)),
        Route("/api/heliostats", get(api_heliostats)),
        Route("/api/heliostats/{hid}", get(api_heliostat)),
        Route("/api/heliostats/{hid}/image.png", get(api_image)),
        Route("/api/heliostats/{hid}/{step}", post(api_step), methods=["POST"]),
        Route("/api/heliostats/{hid}/{step}", refuse_get, methods=["GET"]),
        Route("/api/campaign", get(api_campaign)),
        Route("/api/campaign/{action}", post(api_campaign_action), methods=["POST"]),
        Route("/api/campaign/{action}", refuse_get, methods=["GET"]),
        Route("/api/night", get(api_night)),
        Route("/api/night/{action}", post(api_night_action), methods=["POST"]),
        Route("/api/night/{action}", refuse_get, methods=["GET"]),
        Route("/api/reports", get(api_reports)),
        Route("/reports/campaign/{cid:int}/", get(campaign_report)),
        Route("/reports/campaign/{cid:int}/{file:path}", get(campaign_report)),
        Route("/reports/night/{idx:int}/", get(night_report)),
        Route("/reports/night/{idx:int}/{file:path}", get(night_report)),
        Route("/reports/files/{file:path}", get(report_files)),
        Route("/api/events", events),
        *plant_routes(c, access, post, get, page),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    return Starlette(routes=routes, exception_handlers={HTTPException: _http_error, Exception: _server_error})


async def _http_error(request: Request, exc: HTTPException) -> Response:
    """Starlette's own answers (no such route 404, wrong method 405, …) as JSON like every other."""
    kind = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "refused")
    message = {404: f"no such page or API: {request.url.path}",
               405: f"{request.method} is not allowed on {request.url.path}"}.get(exc.status_code, exc.detail)
    return JSONResponse({"ok": False, "error": message, "kind": kind}, exc.status_code, headers=exc.headers)


async def _server_error(request: Request, exc: Exception) -> Response:
    """A bug: still JSON (the traceback goes to the server's log, not to the page)."""
    return JSONResponse({"ok": False, "error": f"internal error ({type(exc).__name__})", "kind": "internal"},
                        500)


def _needed(request: Request, default: str) -> str:
    """The role a POST needs: recording a reference case changes the error library (engineer)."""
    return "engineer" if request.path_params.get("step") == "record" else default


class _Refused(Exception):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message
