"""The console's web application (Starlette): pages, JSON, live events, review, export.

Pages are small HTML shells; ``static/console.js`` draws them from the JSON routes, and
every asset is served from :mod:`nodes.console`'s ``static/`` folder (no CDN: a site may
have no internet). Reads are open to whoever reaches the port (loopback by default); the one
write, a review decision, needs the console's token (``X-Console-Token`` header or a
``token`` form field, compared in constant time). Every path comes through
:class:`nodes.console.paths.RunsRoot`; request bodies over :data:`MAX_BODY_BYTES` and URLs
over :data:`MAX_URL_BYTES` are refused, and so are hosts other than the bound one (a web
page elsewhere cannot reach the console through DNS rebinding).
"""

from __future__ import annotations

import asyncio
import hmac
import html
import json
import os
import urllib.parse
from dataclasses import dataclass, field
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from nodes.console import export
from nodes.console.live import RunFollower
from nodes.console.paths import PathRefused, RunsRoot
from nodes.console.review import GalleryDesk, ReviewError, check_world, decide, gallery_choice
from nodes.console.runs import MAX_RUNS, list_runs, run_info
from nodes.console.site_store import SiteStore, check_place
from store import StoreError

STATIC_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")
#: the largest request body (a review decision is a few hundred bytes)
MAX_BODY_BYTES = 16_384
#: the longest path and query string
MAX_URL_BYTES = 2_048
#: live event streams served at once
MAX_STREAMS = 16
#: seconds between two polls of a running run's files
POLL_S = 0.5
TOKEN_HEADER = "x-console-token"
CSP = (
    "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
    "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
)
#: run files (a run's own report.html) are shown sandboxed: no script, no same origin
FILE_CSP = "sandbox; default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'"


@dataclass
class ConsoleConfig:
    """What ``btrun console`` was started with."""

    runs: str
    token: str
    gallery: str | None = None
    store: str | None = None  # the site store's URL (None: the runs folder only)
    hosts: list[str] = field(default_factory=lambda: ["127.0.0.1", "localhost", "[::1]"])


class Guard:
    """ASGI middleware: refuses long URLs, methods other than GET/HEAD/POST and bodies over
    the limit (by ``Content-Length`` and by counting what arrives), and adds the security
    headers to every answer."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        raw = scope.get("raw_path") or scope["path"].encode()
        if len(raw) + len(scope.get("query_string") or b"") > MAX_URL_BYTES:
            await _plain(414, "URL too long")(scope, receive, send)
            return
        if scope["method"] not in ("GET", "HEAD", "POST"):
            await _plain(405, "method not allowed")(scope, receive, send)
            return
        length = dict(scope.get("headers") or []).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > MAX_BODY_BYTES):
            await _plain(413, "request body too large")(scope, receive, send)
            return
        seen = 0

        async def counted() -> dict:
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > MAX_BODY_BYTES:
                raise BodyTooLarge()
            return message

        async def secured(message: dict) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers") or [])
                names = {k.lower() for k, _ in headers}
                extra = [
                    (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer"),
                    (b"x-frame-options", b"DENY"),
                ]
                if b"content-security-policy" not in names:
                    extra.append((b"content-security-policy", CSP.encode()))
                message = {**message, "headers": headers + extra}
            await send(message)

        try:
            await self.app(scope, counted, secured)
        except BodyTooLarge:
            await _plain(413, "request body too large")(scope, receive, send)


class BodyTooLarge(Exception):
    """A request body grew past :data:`MAX_BODY_BYTES` while it arrived."""


def same_origin(headers: Any) -> bool:
    """False when a browser says the request comes from another site: an ``Origin`` whose
    host is not the request's ``Host``, or ``Sec-Fetch-Site: cross-site``. A client that
    sends neither (curl, a script with the token) is not a browser page: allowed."""
    if headers.get("sec-fetch-site", "").lower() == "cross-site":
        return False
    origin = headers.get("origin")
    if not origin or origin == "null":
        return origin != "null"
    return urllib.parse.urlsplit(origin).netloc.lower() == headers.get("host", "").lower()


def attachment(filename: str) -> str:
    """A ``Content-Disposition`` for a download named ``filename`` in any script (RFC 6266:
    an ASCII fallback, and the UTF-8 name percent-encoded): headers are Latin-1, and a run
    named ``倉庫 Лагер`` made the export a 500."""
    fallback = "".join(
        c if c.isascii() and c.isprintable() and c not in '"\\' else "_" for c in filename
    )
    if fallback == filename:
        return f'attachment; filename="{filename}"'
    return f"attachment; filename=\"{fallback}\"; filename*=UTF-8''{urllib.parse.quote(filename, safe='')}"


def _plain(status: int, text: str) -> Response:
    return Response(text + "\n", status_code=status, media_type="text/plain")


def _shell(page: str, title: str, run: str = "") -> Response:
    """A page: the shell console.js draws into."""
    body = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{html.escape(title)} - btrun console</title>
<link rel="stylesheet" href="/static/console.css">
<script src="/static/common.js" defer></script>
<script src="/static/console.js" defer></script>
<script src="/static/review.js" defer></script>
</head><body>
<header><a href="/" class="brand">btrun console</a>
<span id="token-state"></span></header>
<main id="app" data-page="{page}" data-run="{html.escape(run, quote=True)}">
<p class="loading">loading...</p></main>
</body></html>
"""
    return Response(body, media_type="text/html; charset=utf-8")


def _refused(exc: PathRefused) -> Response:
    return _plain(exc.status, str(exc))


def make_app(config: ConsoleConfig) -> Starlette:
    """The console application over ``config.runs``."""
    root = RunsRoot(config.runs)
    desk = GalleryDesk()
    site = SiteStore(config.store) if config.store else None
    streams = {"open": 0}

    async def index(request: Request) -> Response:
        return _shell("index", "runs")

    async def run_page(request: Request) -> Response:
        name = request.path_params["name"]
        try:
            root.run_dir(name)
        except PathRefused as exc:
            return _refused(exc)
        return _shell("run", name, name)

    async def review_page(request: Request) -> Response:
        name = request.path_params["name"]
        try:
            root.run_dir(name)
        except PathRefused as exc:
            return _refused(exc)
        return _shell("review", f"review {name}", name)

    async def api_runs(request: Request) -> Response:
        skipped: list[str] = []
        runs = await run_in_threadpool(list_runs, root, skipped)
        for r in runs:
            r["source"] = "folder"
        note = None
        if site is not None:
            try:
                runs += await run_in_threadpool(site.other_runs, root, MAX_RUNS)
                # one list, the latest started first, wherever a run is known from
                runs.sort(key=lambda r: (r.get("started") or 0.0, r["name"]), reverse=True)
            except StoreError as exc:
                note = f"the site store cannot be read: {exc}; showing the runs folder only"
        shown = site.shown if site is not None else None
        body = {"runs": runs, "store": shown, "store_note": note, "skipped": ", ".join(skipped)}
        return JSONResponse(body)

    async def place_page(request: Request) -> Response:
        place = request.path_params["place"]
        try:
            check_place(place)
        except PathRefused as exc:
            return _refused(exc)
        return _shell("place", f"place {place}", place)

    async def api_place(request: Request) -> Response:
        place = request.path_params["place"]
        if site is None:
            return JSONResponse({"error": "no site store: start btrun console --store URL"}, 404)
        try:
            found = await run_in_threadpool(site.history, root, place)
        except PathRefused as exc:
            return JSONResponse({"error": str(exc)}, status_code=exc.status)
        except StoreError as exc:
            return JSONResponse({"error": f"the site store cannot be read: {exc}"}, 503)
        return JSONResponse({"place": place, "store": site.shown, "history": found})

    async def api_run(request: Request) -> Response:
        name = request.path_params["name"]
        try:
            info = await run_in_threadpool(run_info, root, name, True)
        except PathRefused as exc:
            return _refused(exc)
        info["gallery"] = await run_in_threadpool(_gallery_info, root, name, config.gallery)
        info["store"] = site.shown if site is not None else None
        return JSONResponse(info)

    async def events(request: Request) -> Response:
        name = request.path_params["name"]
        try:
            run_dir = root.run_dir(name)
        except PathRefused as exc:
            return _refused(exc)
        if streams["open"] >= MAX_STREAMS:
            return _plain(503, "too many live views open")
        follower = RunFollower(run_dir)
        streams["open"] += 1

        async def stream() -> Any:
            try:
                yield "retry: 2000\n\n"
                while True:
                    for event, data in await run_in_threadpool(follower.poll):
                        yield f"event: {event}\ndata: {json.dumps(data)}\n\n"
                    if follower.done:
                        yield "event: end\ndata: {}\n\n"
                        return
                    await asyncio.sleep(POLL_S)
            finally:
                streams["open"] -= 1

        headers = {"Cache-Control": "no-store", "X-Accel-Buffering": "no"}
        return StreamingResponse(stream(), media_type="text/event-stream", headers=headers)

    async def run_file(request: Request) -> Response:
        try:
            path, media = root.file(request.path_params["name"], request.path_params["path"])
        except PathRefused as exc:
            return _refused(exc)
        return FileResponse(path, media_type=media, headers={"Content-Security-Policy": FILE_CSP})

    async def download(request: Request) -> Response:
        name, kind, fmt = (request.path_params[k] for k in ("name", "kind", "fmt"))
        if kind not in export.KINDS or fmt not in ("csv", "xlsx"):
            return _plain(404, "no such export")
        try:
            info = await run_in_threadpool(run_info, root, name, True)
        except PathRefused as exc:
            return _refused(exc)
        if info.get("rows_error"):  # never an empty count handed to a WMS as if it were one
            return _plain(409, f"the run's rows cannot be read: {info['rows_error']}")
        if info.get("no_inventory"):  # a header-only file would read as an empty count
            return _plain(
                409,
                "the run has no inventory.json (it stopped before its first place, or the "
                "folder is no inventory): nothing to export",
            )
        if info.get("review_error"):  # nor a count without the operators' decisions
            return _plain(409, f"the run's review decisions cannot be read: {info['review_error']}")
        columns, lines = export.table(info, kind)
        disposition = {"Content-Disposition": attachment(f"{name}-{kind}.{fmt}")}
        if fmt == "csv":
            body = export.to_csv(columns, lines)
            return Response(body, media_type="text/csv; charset=utf-8", headers=disposition)
        body = await run_in_threadpool(export.to_xlsx, columns, lines, kind)
        media = "application/vnd.openxmlformats-officedocument.spreadsheetml.sheet"
        return Response(body, media_type=media, headers=disposition)

    async def review(request: Request) -> Response:
        name = request.path_params["name"]
        try:
            fields = await _body(request)
        except BodyTooLarge:
            return _plain(413, "request body too large")
        except ValueError as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        if not same_origin(request.headers):  # a page of another site posting with a token
            return JSONResponse({"error": "a review comes from the console's own page"}, 403)
        token = request.headers.get(TOKEN_HEADER) or str(fields.get("token") or "")
        if not hmac.compare_digest(token.encode(), config.token.encode()):
            refused = {"error": "a review needs the console's token", "token_refused": True}
            return JSONResponse(refused, 403)
        try:
            record = await run_in_threadpool(decide, root, name, fields, config.gallery, desk)
        except PathRefused as exc:
            return _refused(exc)
        except ReviewError as exc:
            return JSONResponse({"error": str(exc)}, status_code=exc.status)
        return JSONResponse({"decision": record})

    routes = [
        Route("/", index),
        Route("/favicon.ico", lambda request: Response(status_code=204)),
        Route("/runs/{name}", run_page),
        Route("/runs/{name}/review", review_page),
        Route("/places/{place}", place_page),
        Route("/api/places/{place}", api_place),
        Route("/api/runs", api_runs),
        Route("/api/runs/{name}", api_run),
        Route("/api/runs/{name}/events", events),
        Route("/api/runs/{name}/review", review, methods=["POST"]),
        Route("/files/{name}/{path:path}", run_file),
        Route("/export/{name}/{kind}.{fmt}", download),
        Mount("/static", StaticFiles(directory=STATIC_DIR, follow_symlink=False), name="static"),
    ]
    middleware = [Middleware(Guard), Middleware(TrustedHostMiddleware, allowed_hosts=config.hosts)]
    app = Starlette(routes=routes, middleware=middleware)
    app.state.site = site
    app.state.streams = streams  # live views open now (tests)
    return app


def _gallery_info(root: RunsRoot, name: str, option: str | None) -> dict:
    """Which gallery the run's review decisions go to, for the page: ``path`` (None: none),
    ``source``, ``world``, ``exists``, ``problem`` (why a decision that changes the gallery
    would be refused) and its ``identities``."""
    choice = gallery_choice(root, root.run_dir(name), option)
    path = choice["path"]
    problem = choice["problem"]
    if path is not None and problem is None:
        try:
            check_world(choice)
        except ReviewError as exc:
            problem = str(exc)
    return {
        **choice,
        "problem": problem,
        "exists": bool(path) and os.path.isfile(path),
        "identities": _identities(path) if path and problem is None else [],
    }


def _identities(path: str) -> list[str]:
    """The identities of the review gallery file ([] before the first decision creates it)."""
    if not os.path.isfile(path):
        return []
    try:
        from perception.gallery import Gallery

        with Gallery.open(path) as g:
            return g.identities()
    except Exception:  # noqa: BLE001 - a damaged gallery shows as none; a decision says why
        return []


async def _body(request: Request) -> dict:
    """A POST body (JSON, or a urlencoded form) of at most :data:`MAX_BODY_BYTES`."""
    data = b""
    async for chunk in request.stream():
        data += chunk
        if len(data) > MAX_BODY_BYTES:
            raise BodyTooLarge()
    kind = request.headers.get("content-type", "").split(";")[0].strip()
    if kind == "application/x-www-form-urlencoded":
        pairs = urllib.parse.parse_qsl(data.decode("utf-8", "replace"), max_num_fields=20)
        return dict(pairs)
    try:
        doc = json.loads(data or b"{}")
    except (ValueError, RecursionError):
        raise ValueError("the body is not JSON") from None
    if not isinstance(doc, dict):
        raise ValueError("the body must be a JSON object")
    return doc
