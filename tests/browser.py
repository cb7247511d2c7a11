"""A page opened in headless Chromium through the DevTools protocol (a websocket, tornado's client:
installed with Dask): what the console said, which images did not load, a screenshot. No new
dependency; the tests that use it skip when no Chromium is installed."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    return next((found for name in CANDIDATES if (found := shutil.which(name))), None)


@dataclass
class Visit:
    errors: list[str] = field(default_factory=list)  # console errors, uncaught exceptions, failed loads
    broken_images: list[str] = field(default_factory=list)
    images: int = 0
    screenshot: bytes = b""
    values: dict = field(default_factory=dict)  # the results of the extra expressions asked for


# every image loaded now (they are lazy), then which did not decode
_IMAGES = """
Promise.all(Array.from(document.images).map(function (img) {
  img.loading = "eager";
  return img.decode().then(function () { return img.naturalWidth > 0 ? null : img.src; },
                           function () { return img.src; });
})).then(function (bad) { return JSON.stringify({count: document.images.length,
                                                 broken: bad.filter(function (b) { return b; })}); })
"""


async def _visit(binary: str, url: str, expressions: dict[str, str], timeout: float, scroll_to: str | None) -> Visit:
    from tornado.websocket import websocket_connect

    visit = Visit()
    with tempfile.TemporaryDirectory() as profile:
        log_path = Path(profile) / "stderr.log"  # a file, not a pipe: chromium never blocks on it
        with open(log_path, "wb") as log:
            process = subprocess.Popen(
                [binary, "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-extensions",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 f"--user-data-dir={profile}/data", "--remote-debugging-port=0", "--window-size=1400,1000",
                 "about:blank"], stdout=subprocess.DEVNULL, stderr=log,
                start_new_session=True)  # its own process group: its helpers die with it
        try:
            deadline = time.monotonic() + timeout
            endpoint = None
            while endpoint is None and time.monotonic() < deadline:
                match = re.search(r"DevTools listening on (ws://\S+)", log_path.read_text(errors="replace"))
                if match:
                    endpoint = match.group(1)
                elif process.poll() is not None:
                    raise RuntimeError(f"chromium exited with {process.returncode} before listening")
                else:
                    await asyncio.sleep(0.05)
            if endpoint is None:
                raise TimeoutError("chromium did not open its DevTools endpoint")
            socket = await websocket_connect(endpoint, max_message_size=256 * 1024 * 1024)
            counter = iter(range(1, 1 << 30))
            pending: dict[int, asyncio.Future] = {}
            events: asyncio.Queue = asyncio.Queue()

            async def reader():
                while (message := await socket.read_message()) is not None:
                    data = json.loads(message)
                    if "id" in data and data["id"] in pending:
                        pending.pop(data["id"]).set_result(data)
                    else:
                        await events.put(data)

            task = asyncio.ensure_future(reader())

            async def call(method: str, session: str | None = None, **params) -> dict:
                number = next(counter)
                future = asyncio.get_running_loop().create_future()
                pending[number] = future
                message = {"id": number, "method": method, "params": params}
                if session:
                    message["sessionId"] = session
                await socket.write_message(json.dumps(message))
                reply = await asyncio.wait_for(future, max(1.0, deadline - time.monotonic()))
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

            target = (await call("Target.createTarget", url="about:blank"))["targetId"]
            session = (await call("Target.attachToTarget", targetId=target, flatten=True))["sessionId"]
            for domain in ("Page", "Runtime", "Log"):
                await call(f"{domain}.enable", session)
            await call("Page.navigate", session, url=url)

            async def evaluate(expression: str):
                result = await call("Runtime.evaluate", session, expression=expression, awaitPromise=True,
                                    returnByValue=True)
                if "exceptionDetails" in result:
                    raise RuntimeError(f"{expression[:60]}...: {result['exceptionDetails'].get('text')}")
                return result["result"].get("value")

            # loaded: this page (not the blank one it replaced), with its scripts run
            while await evaluate("location.href + ' ' + document.readyState") != f"{url} complete":
                if time.monotonic() > deadline:
                    raise TimeoutError(f"{url} did not finish loading")
                await asyncio.sleep(0.05)

            images = json.loads(await evaluate(_IMAGES))
            visit.images, visit.broken_images = images["count"], images["broken"]
            for name, expression in expressions.items():
                visit.values[name] = await evaluate(expression)
            await evaluate(f"document.getElementById({json.dumps(scroll_to)}).scrollIntoView()" if scroll_to
                           else "window.scrollTo(0, 0)")
            shot = await call("Page.captureScreenshot", session, format="png")
            visit.screenshot = base64.b64decode(shot["data"])
            await asyncio.sleep(0.5)  # what the page logged last reaches us
            while not events.empty():
                _note(visit, events.get_nowait())
            socket.close()  # the reader ends once the closing handshake is done: no socket left open
            try:
                await asyncio.wait_for(task, 10)
            except (asyncio.TimeoutError, asyncio.CancelledError):
                pass
            if socket.protocol is not None and socket.protocol.stream is not None:
                socket.protocol.stream.close()
        finally:
            # the whole group: a renderer or crash handler left alive kept writing into the profile, and
            # removing it failed ("Directory not empty": seen once in a fresh clone's make test)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=30)
    return visit


def _note(visit: Visit, event: dict) -> None:
    method, params = event.get("method"), event.get("params", {})
    if method == "Runtime.exceptionThrown":
        details = params.get("exceptionDetails", {})
        visit.errors.append(f"exception: {details.get('exception', {}).get('description') or details.get('text')}")
    elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
        visit.errors.append("console.error: " + " ".join(str(a.get("value", a.get("description")))
                                                         for a in params.get("args", [])))
    elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
        entry = params["entry"]
        visit.errors.append(f"{entry.get('source')}: {entry.get('text')} {entry.get('url', '')}".strip())


def open_page(binary: str, path: Path, expressions: dict[str, str] | None = None, timeout: float = 120,
              scroll_to: str | None = None) -> Visit:
    """Load ``path`` (a local file) in headless Chromium ``binary``; see :class:`Visit`. The
    screenshot shows the top of the page, or the element of id ``scroll_to``."""
    return asyncio.run(_visit(binary, Path(path).resolve().as_uri(), expressions or {}, timeout, scroll_to))
