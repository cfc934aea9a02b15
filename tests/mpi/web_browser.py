#!/usr/bin/env python3
"""Drives Debian's headless chromium over the DevTools protocol against a
running pointillist-web (tests/mpi/web_test.sh starts the job and the server):
loads the viewer, waits for a frame, screenshots, drags, waits for a newer
frame, screenshots again, and checks the frames are not empty, differ, and
that the page counts frames/s. A second, raw WebSocket sends malformed and
oversized messages and leaves abruptly; the page must not notice.

  web_browser.py URL WORK_DIR [--save DIR]
  web_browser.py URL WORK_DIR --raw frame     one frame over a raw WebSocket, no browser
  web_browser.py URL WORK_DIR --raw refused   the relay's error and close (service refuses it)
"""
import argparse
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import time
import urllib.request
import zlib

import numpy as np
import websocket  # Debian python3-websocket (websocket-client)

WIDTH, HEIGHT = 1280, 720


def fail(message):
    print(f"FAIL: {message}", flush=True)
    sys.exit(1)


def decode_png(data):
    """8-bit RGB or RGBA, non-interlaced PNG (what chromium writes) to an HxWx3 array."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        fail("screenshot is not a PNG")
    pos, idat, header = 8, [], None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        pos += 12 + length
    width, height, depth, color, _, _, interlace = header
    if depth != 8 or color not in (2, 6) or interlace != 0:
        fail(f"unexpected PNG format depth {depth} color {color} interlace {interlace}")
    channels = 3 if color == 2 else 4
    stride = width * channels
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8)
    raw = raw.reshape(height, stride + 1)
    out = np.zeros((height, stride), dtype=np.uint8)
    previous = np.zeros(stride, dtype=np.int32)
    for y in range(height):
        kind, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        if kind == 0:
            row = line
        elif kind == 1:  # Sub: a running sum per channel
            row = np.cumsum(line.reshape(-1, channels), axis=0).reshape(-1) & 0xFF
        elif kind == 2:  # Up
            row = (line + previous) & 0xFF
        else:  # Average and Paeth depend on the pixel to the left: one at a time
            row = np.zeros(stride, dtype=np.int32)
            line_l, prev_l, row_l = line.tolist(), previous.tolist(), [0] * stride
            for i in range(stride):
                a = row_l[i - channels] if i >= channels else 0
                b = prev_l[i]
                if kind == 3:
                    value = line_l[i] + ((a + b) >> 1)
                else:
                    c = prev_l[i - channels] if i >= channels else 0
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    value = line_l[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)
                row_l[i] = value & 0xFF
            row = np.array(row_l, dtype=np.int32)
        out[y] = row
        previous = row.astype(np.int32)
    return out.reshape(height, width, channels)[:, :, :3]


class DevTools:
    def __init__(self, url):
        self.socket = websocket.create_connection(url, timeout=60, suppress_origin=True)
        self.next_id = 1

    def call(self, method, **params):
        ident = self.next_id
        self.next_id += 1
        self.socket.send(json.dumps({"id": ident, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv())
            if message.get("id") == ident:
                if "error" in message:
                    fail(f"{method}: {message['error']}")
                return message.get("result", {})

    def evaluate(self, expression):
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in result:
            fail(f"page error evaluating {expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, expression, seconds, what):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.1)
        errors = self.evaluate("JSON.stringify(window.pointillist && window.pointillist.errors)")
        fail(f"{what} within {seconds} s (page errors: {errors})")

    def screenshot(self):
        import base64
        return base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])

    def key(self, key, code):
        for kind in ("keyDown", "keyUp"):
            self.call("Input.dispatchKeyEvent", type=kind, key=key, code=code,
                      text=key if kind == "keyDown" else "")

    def mouse(self, kind, x, y, buttons):
        self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left",
                  buttons=buttons, clickCount=1 if kind != "mouseMoved" else 0)


def start_chromium(work):
    chromium = shutil.which("chromium")
    if chromium is None:
        fail("chromium is not installed (Debian package chromium, see deploy/common.sh)")
    profile = os.path.join(work, "chromium-profile")
    os.makedirs(profile, exist_ok=True)
    log = open(os.path.join(work, "chromium.log"), "w")
    process = subprocess.Popen(
        [chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
         "--remote-debugging-port=0", f"--user-data-dir={profile}",
         f"--window-size={WIDTH},{HEIGHT}", "--hide-scrollbars", "--no-first-run",
         "--no-default-browser-check", "--mute-audio", "about:blank"],
        stdout=log, stderr=log, start_new_session=True)
    port_file = os.path.join(profile, "DevToolsActivePort")
    deadline = time.monotonic() + 60
    while not os.path.exists(port_file) or os.path.getsize(port_file) == 0:
        if process.poll() is not None or time.monotonic() > deadline:
            log.close()
            fail("chromium did not start its DevTools endpoint:\n" +
                 open(os.path.join(work, "chromium.log")).read())
        time.sleep(0.1)
    time.sleep(0.2)
    port = int(open(port_file).read().split()[0])
    return process, port


def frame_mask(tools):
    """Where the frame shows: everything but the overlays (their text changes)."""
    rects = tools.evaluate(
        "['stats','help'].map(id => { const r = document.getElementById(id)"
        ".getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; })")
    mask = np.ones((HEIGHT, WIDTH), dtype=bool)
    for left, top, right, bottom in rects:
        mask[max(0, int(top) - 2):int(bottom) + 2, max(0, int(left) - 2):int(right) + 2] = False
    return mask


def lit_fraction(image, mask):
    """Share of frame pixels unlike the commonest colour (the background)."""
    pixels = image[mask].astype(np.int32)
    keys = (pixels[:, 0] << 16) | (pixels[:, 1] << 8) | pixels[:, 2]
    values, counts = np.unique(keys, return_counts=True)
    background = values[np.argmax(counts)]
    bg = np.array([(background >> 16) & 0xFF, (background >> 8) & 0xFF, background & 0xFF])
    return float(np.mean(np.abs(pixels - bg).max(axis=1) > 24))


def check_raw_websocket(url):
    """Malformed messages get an error back; an oversized one ends only that connection."""
    ws_url = url.replace("http://", "ws://").rstrip("/") + "/ws"
    ws = websocket.create_connection(ws_url, timeout=30)
    info = json.loads(ws.recv())
    if info.get("type") != "info":
        fail(f"a raw WebSocket got {info} first, not the dataset's info")
    for bad in ["not json", '{"type":"shutdown"}',
                '{"type":"camera","id":1,"eye":[0,0,0],"target":[0,0,0]}']:
        ws.send(bad)
        reply = json.loads(ws.recv())
        if reply.get("type") != "error":
            fail(f"malformed message {bad!r} got {reply}")
        print(f"malformed {bad!r} -> error: {reply['message']}")
    ws.send("x" * 100000)  # over the cap: Beast closes this connection (1009)
    try:
        while True:
            opcode, _ = ws.recv_data()
            if opcode == websocket.ABNF.OPCODE_CLOSE:
                break
    except (websocket.WebSocketConnectionClosedException, ConnectionError):
        pass
    print("oversized message: connection closed")
    ws.close()
    # Another one that leaves mid-frame, without a close handshake.
    ws = websocket.create_connection(ws_url, timeout=30)
    info = json.loads(ws.recv())
    bmin, bmax = info["bounds_min"], info["bounds_max"]
    ws.send(json.dumps({"type": "camera", "id": 1, "eye": [bmax[0] * 2, bmax[1] * 2, bmax[2] * 2],
                        "target": [(a + b) / 2 for a, b in zip(bmin, bmax)]}))
    ws.sock.shutdown(2)
    ws.sock.close()


def raw_frame(url):
    """A camera over a raw WebSocket gets the frame's metadata and a JPEG."""
    ws = websocket.create_connection(url.replace("http://", "ws://").rstrip("/") + "/ws", timeout=60)
    info = json.loads(ws.recv())
    if info.get("type") != "info":
        fail(f"first message {info}, not the dataset's info")
    bmin, bmax = info["bounds_min"], info["bounds_max"]
    center = [(a + b) / 2 for a, b in zip(bmin, bmax)]
    ws.send(json.dumps({"type": "camera", "id": 42, "eye": [c + (b - a) for a, b, c in
                                                            zip(bmin, bmax, center)],
                        "target": center, "width": 640, "height": 360}))
    meta = json.loads(ws.recv())
    if meta.get("type") != "frame" or meta.get("id") != 42 or meta.get("status") != "ok":
        fail(f"no frame for the camera: {meta}")
    image = ws.recv()
    if not isinstance(image, bytes) or image[:2] != b"\xff\xd8" or len(image) != meta["bytes"]:
        fail("the frame is not the JPEG its metadata announces")
    print(f"raw WebSocket frame: {meta}")
    ws.close()


def raw_refused(url):
    """When the service does not answer the relay, the browser hears why and is closed."""
    ws = websocket.create_connection(url.replace("http://", "ws://").rstrip("/") + "/ws", timeout=60)
    message = json.loads(ws.recv())
    if message.get("type") != "error":
        fail(f"expected an error from the relay, got {message}")
    print(f"relay refused: {message['message']}")
    try:
        opcode, _ = ws.recv_data()
        if opcode != websocket.ABNF.OPCODE_CLOSE:
            fail("the WebSocket stayed open after the error")
    except (websocket.WebSocketConnectionClosedException, ConnectionError):
        pass


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("url")
    parser.add_argument("work")
    parser.add_argument("--save", help="keep the screenshots in this folder")
    parser.add_argument("--drag-seconds", type=float, default=4.0)
    parser.add_argument("--raw", choices=["frame", "refused"])
    args = parser.parse_args()
    if args.raw == "frame":
        return raw_frame(args.url)
    if args.raw == "refused":
        return raw_refused(args.url)

    process, port = start_chromium(args.work)
    try:
        targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list"))
        page = next(t for t in targets if t.get("type") == "page")
        tools = DevTools(page["webSocketDebuggerUrl"])
        tools.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT,
                   deviceScaleFactor=1, mobile=False)
        tools.call("Page.enable")
        tools.call("Page.navigate", url=args.url)
        tools.wait_for("window.pointillist && window.pointillist.framesDrawn >= 1", 90,
                       "no frame on the page")
        time.sleep(0.3)
        first = decode_png(tools.screenshot())
        state0 = tools.evaluate("JSON.stringify(window.pointillist)")
        state0 = json.loads(state0)
        print(f"first frame {state0['lastFrameId']}: {state0['lastMeta']}")

        check_raw_websocket(args.url)

        # Orbit: press, move right and a little down for a while, release.
        x, y = WIDTH // 2, HEIGHT // 2
        tools.mouse("mousePressed", x, y, 1)
        start_frames = tools.evaluate("window.pointillist.framesDrawn")
        start = time.monotonic()
        step = 0
        fps_samples = []
        while time.monotonic() - start < args.drag_seconds:
            step += 1
            tools.mouse("mouseMoved", x + 4 * step % 600, y + (step % 60), 1)
            if step % 30 == 0:
                fps_samples.append(tools.evaluate("window.pointillist.fps"))
            # About 120 moves/s, as a mouse gives, unless dispatching is slower.
            time.sleep(max(0.0, start + step / 120 - time.monotonic()))
        elapsed = time.monotonic() - start
        drag_frames = tools.evaluate("window.pointillist.framesDrawn") - start_frames
        stats_text = tools.evaluate("document.getElementById('statsText').textContent")
        tools.mouse("mouseReleased", x + 4 * step % 600, y + (step % 60), 0)
        tools.wait_for(f"window.pointillist.lastFrameId > {state0['lastFrameId']}", 60,
                       "no newer frame after the drag")
        time.sleep(0.5)
        second = decode_png(tools.screenshot())
        state1 = json.loads(tools.evaluate("JSON.stringify(window.pointillist)"))
        print(f"stats while dragging: {stats_text!r}")
        print(f"drag of {elapsed:.1f} s, {step / elapsed:.0f} mouse moves/s: {drag_frames} frames "
              f"drawn, {drag_frames / elapsed:.2f} frames/s; page counter samples "
              f"{['%.1f' % s for s in fps_samples]}")
        print(f"last frame {state1['lastFrameId']}: {state1['lastMeta']}")
        if state1["errors"]:
            fail(f"the page shows errors: {state1['errors']}")

        if args.save:
            os.makedirs(args.save, exist_ok=True)
            for name, image in (("before", first), ("after", second)):
                # PPM: readable anywhere without a PNG encoder here.
                with open(os.path.join(args.save, f"{name}.ppm"), "wb") as out:
                    out.write(b"P6 %d %d 255\n" % (image.shape[1], image.shape[0]))
                    out.write(image.tobytes())

        if first.shape[:2] != (HEIGHT, WIDTH):
            fail(f"screenshot is {first.shape[1]}x{first.shape[0]}, not {WIDTH}x{HEIGHT}")
        mask = frame_mask(tools)
        lit0, lit1 = lit_fraction(first, mask), lit_fraction(second, mask)
        changed = float(np.mean(
            np.abs(first.astype(np.int32) - second.astype(np.int32)).max(axis=2)[mask] > 24))
        print(f"frame area: {lit0:.1%} lit before, {lit1:.1%} after, {changed:.1%} of pixels changed")
        if lit0 < 0.05 or lit1 < 0.05:
            fail("a screenshot's frame area is (nearly) empty")
        if changed < 0.02:
            fail("the image did not change with the drag")
        match = re.search(r"([0-9.]+) frames/s", stats_text)
        if not match or float(match.group(1)) <= 0:
            fail(f"the stats show no frames/s: {stats_text!r}")
        if drag_frames < 2:
            fail(f"only {drag_frames} frames while dragging")

        # Live options from the keyboard: splats (2), then coarser detail (]).
        before = tools.evaluate("window.pointillist.lastFrameId")
        for key, code in (("2", "Digit2"), ("]", "BracketRight")):
            tools.key(key, code)
        tools.wait_for("window.pointillist.lastMeta && window.pointillist.lastMeta.mode === 'splats'"
                       f" && window.pointillist.lastMeta.lod_pixels > 1.4"
                       f" && window.pointillist.lastFrameId > {before}", 60,
                       "no frame drawn as splats at coarser detail after the keys")
        time.sleep(0.5)
        third = decode_png(tools.screenshot())
        meta = json.loads(tools.evaluate("JSON.stringify(window.pointillist.lastMeta)"))
        lit2 = lit_fraction(third, mask)
        print(f"after keys 2 and ]: drawn as {meta['mode']} at {meta['lod_pixels']} px, "
              f"{meta['splats']} splats, {lit2:.1%} lit")
        if lit2 < 0.05:
            fail("the splats frame is (nearly) empty")
        errors = json.loads(tools.evaluate("JSON.stringify(window.pointillist.errors)"))
        if errors:
            fail(f"the page shows errors after the keys: {errors}")
        print("browser checks passed")
    finally:
        try:
            os.killpg(process.pid, signal.SIGTERM)
            process.wait(timeout=10)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


if __name__ == "__main__":
    main()
