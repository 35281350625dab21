#!/usr/bin/env python3
"""Screenshot a Rerun recording as the web viewer shows it (a look at the view, for humans).

    python scripts/screenshot_rrd.py FILE.rrd OUT.png [--wait 60] [--size 1600x1000]

Serves FILE.rrd with ``rerun --serve-web`` on free ports, opens the web viewer in headless
Chromium (Debian's /usr/bin/chromium through Playwright; software WebGL via SwiftShader),
waits ``--wait`` seconds for the viewer to load and render, saves the screenshot and stops
the server. Needs ``pip install playwright`` and a Chromium; no ``playwright install``.
Not part of the package: a development tool only.

Under software rendering the viewer ingests slowly: a 1-2 minute replay (a few MB) needs
--wait 150-200 before every plot is filled; take --shots 3 to watch it fill. --click X,Y
clicks viewport pixels afterwards and saves OUT-clickN.png. At 1600x1000, a replay with a GPS
track and an estimated track has its tabs at "GPS track" 1097,517, "track" 1202,517,
"summary" 1307,517, "events" 1388,517, "diagnostics" 1457,517 (the legend's column sits left of
them), and the diagnostics' estimator tabs on the row below (y 546: ncs-eskf 1317, eq-kf 1394 on
a replay of all nine); the middle of the timeline is 830,986.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from urllib.parse import quote

CHROMIUM_ARGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--enable-webgl",
    "--no-sandbox",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-default-apps",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_port(port: int, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket() as s:
            s.settimeout(0.5)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return True
        time.sleep(0.2)
    return False


def shoot(page, out: str) -> None:
    """Screenshot; falls back to the DevTools protocol when the page is too busy
    (software WebGL can keep the renderer from producing a frame for Playwright)."""
    try:
        page.screenshot(path=out, timeout=90_000, animations="disabled")
        return
    except Exception as e:  # noqa: BLE001 - any failure: try the raw protocol
        print(f"page.screenshot failed ({type(e).__name__}); trying CDP", file=sys.stderr)
    import base64
    cdp = page.context.new_cdp_session(page)
    data = cdp.send("Page.captureScreenshot", {"format": "png"})["data"]
    with open(out, "wb") as f:
        f.write(base64.b64decode(data))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rrd")
    ap.add_argument("out")
    ap.add_argument("--wait", type=float, default=60.0, help="seconds to let the viewer load")
    ap.add_argument("--size", default="1600x1000", help="viewport WIDTHxHEIGHT")
    ap.add_argument("--chromium", default=shutil.which("chromium") or "/usr/bin/chromium")
    ap.add_argument("--renderer", default="webgl", choices=["webgl", "webgpu"],
                    help="the web viewer's graphics backend (webgl works with SwiftShader)")
    ap.add_argument("--color-scheme", default="light", choices=["light", "dark"],
                    help="the browser's preferred colour scheme (the viewer follows it)")
    ap.add_argument("--click", action="append", default=[], metavar="X,Y",
                    help="after the wait, click here (viewport pixels) and take one more "
                         "screenshot OUT-clickN.png; repeatable (e.g. to open a tab)")
    ap.add_argument("--shots", type=int, default=1,
                    help="take N screenshots spread over the wait (OUT-1.png, ...)")
    args = ap.parse_args(argv)

    from playwright.sync_api import sync_playwright

    if not os.path.exists(args.rrd):
        print(f"{args.rrd}: no such file", file=sys.stderr)
        return 2
    width, height = (int(v) for v in args.size.lower().split("x"))
    web_port, grpc_port = free_port(), free_port()
    rerun = shutil.which("rerun") or "rerun"
    log = tempfile.NamedTemporaryFile("w+", suffix=".log", delete=False)
    server = subprocess.Popen(
        [rerun, "--serve-web", os.path.abspath(args.rrd), "--bind", "127.0.0.1",
         "--web-viewer-port", str(web_port), "--port", str(grpc_port)],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        if not (wait_for_port(web_port, 30) and wait_for_port(grpc_port, 30)):
            log.seek(0)
            print("rerun did not start serving:\n" + log.read(), file=sys.stderr)
            return 1
        grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
        url = (f"http://127.0.0.1:{web_port}/?url={quote(grpc_url, safe='')}"
               f"&renderer={args.renderer}")
        print(f"viewer: {url}", file=sys.stderr)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=args.chromium, headless=True,
                                        args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": width, "height": height},
                                    color_scheme=args.color_scheme)
            messages = []
            page.on("console", lambda m: messages.append(f"{m.type}: {m.text}"))
            page.goto(url, wait_until="domcontentloaded", timeout=120_000)
            shots = max(1, args.shots)
            base, ext = os.path.splitext(args.out)
            for k in range(shots):
                page.wait_for_timeout(1000 * args.wait / shots)
                out = args.out if k == shots - 1 else f"{base}-{k + 1}{ext}"
                shoot(page, out)
                print(f"wrote {out}", file=sys.stderr)
            for k, xy in enumerate(args.click, start=1):
                x, y = (float(v) for v in xy.split(","))
                page.mouse.click(x, y)
                page.wait_for_timeout(8000)
                out = f"{base}-click{k}{ext}"
                shoot(page, out)
                print(f"wrote {out}", file=sys.stderr)
            errors = [m for m in messages if m.startswith("error")]
            if errors:
                print("browser console errors (last 10):\n  " + "\n  ".join(errors[-10:]),
                      file=sys.stderr)
            browser.close()
    finally:
        try:
            os.killpg(server.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()
        log.close()
        os.unlink(log.name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
