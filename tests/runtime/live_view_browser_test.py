"""The live view in a real browser: `mocapd run` with `mocap-sim replay` feeding N actors,
and Debian's Chromium (headless, WebGL on SwiftShader) opening the daemon's page. The page
(opened with the HTTP token once, then on its cookie) must receive frames over the
WebSocket, and a screenshot must show the skeleton: pixels of the skeleton's colour where
the page says its joints are drawn. Fails if the page is
blank or the socket never delivers. Prints what it measured (time to the first frame,
render rate) and saves the screenshot in WORK_DIR.

usage: live_view_browser_test.py MOCAPD MOCAP_SIM CONFIG_DIR WORK_DIR [--subjects N] [--seconds S]
"""
import argparse
import io
import os
import subprocess
import sys
import time

from PIL import Image  # Debian: python3-pil

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from browser import Browser  # noqa: E402
from daemon_harness import Daemon, metrics  # noqa: E402


def skeleton_pixels_found(png, joints, colour, panels, tolerance=60, radius=3):
    """How many of the projected joints have a pixel of the skeleton's colour nearby, of
    those inside the image and not under a panel (the page's HUD and legend, which are
    drawn over the scene); and how much of the image is not background."""
    image = Image.open(io.BytesIO(png)).convert("RGB")
    w, h = image.size
    pixels = image.load()

    def near(p):
        return all(abs(p[k] - colour[k]) <= tolerance for k in range(3))

    inside = found = 0
    for x, y in joints:
        x, y = int(round(x)), int(round(y))
        if not (radius <= x < w - radius and radius <= y < h - radius):
            continue
        if any(left - radius <= x <= right + radius and top - radius <= y <= bottom + radius
               for left, top, right, bottom in panels):
            continue
        inside += 1
        if any(near(pixels[x + dx, y + dy]) for dx in range(-radius, radius + 1) for dy in range(-radius, radius + 1)):
            found += 1
    background = pixels[2, h - 2]
    drawn = sum(1 for x in range(0, w, 4) for y in range(0, h, 4)
                if sum(abs(pixels[x, y][k] - background[k]) for k in range(3)) > 30)
    return inside, found, drawn / ((w // 4) * (h // 4))


def main():
    parser = argparse.ArgumentParser()
    for name in ("mocapd", "mocap_sim", "config_dir", "work"):
        parser.add_argument(name)
    parser.add_argument("--subjects", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=25.0)
    args = parser.parse_args()
    names = [f"actor{k + 1}" for k in range(args.subjects)]
    # With a token, as a stage would run it: the page opens with ?token= once, and its
    # scripts and its WebSocket must get through on the cookie that leaves it.
    token = "live-view-test-token-0123456789"
    daemon = Daemon(args.mocapd, args.config_dir, args.work, subjects=names, lookahead=4, http_token=token)
    replay = subprocess.Popen([args.mocap_sim, "replay", "--humanoid", "walk", "--seconds", str(args.seconds),
                               "--subjects", str(args.subjects), "--corrupt", "medium", "--to", daemon.input, "--from", ""],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    browser = None
    try:
        browser = Browser(width=1280, height=800)
        opened = time.monotonic()
        browser.open(f"http://127.0.0.1:{daemon.http_port}/?token={token}")
        state = None
        deadline = opened + 40
        while time.monotonic() < deadline:
            state = browser.evaluate(
                "window.mocapdView && {frames: mocapdView.framesReceived, fps: mocapdView.renderFps, "
                "first: mocapdView.firstFrameMs, connected: mocapdView.connected, "
                "subjects: Object.keys(mocapdView.subjects).length}")
            # Three seconds of frames: enough to measure the render rate over whole seconds.
            if state and state["frames"] >= 90 and state["fps"] > 0:
                break
            time.sleep(0.25)
        assert state is not None, "the page never ran (mocapdView missing: did three.js load?)"
        assert state["connected"], f"the page's WebSocket never connected: {state}"
        assert state["frames"] > 0, f"the WebSocket delivered no frame: {state}"
        assert state["subjects"] == args.subjects, state
        # Picking a subject centres the view on it, as an operator would look at one actor.
        browser.evaluate("(() => { const s = document.getElementById('subject'); s.value = 'actor1';"
                         " s.dispatchEvent(new Event('change')); return s.value; })()")
        time.sleep(0.5)  # a few more frames drawn where the joints now are
        # Paused, as an operator would to look: the joints are projected and the screenshot
        # taken of the same frame (a walking actor moves 5-10 cm between two browser calls
        # on a busy machine, which once left 13 of 20 joints on their pixels).
        browser.evaluate("(() => { const p = document.getElementById('pause'); p.checked = true;"
                         " p.dispatchEvent(new Event('change')); return p.checked; })()")
        time.sleep(0.3)  # the last frame drawn again, the camera settled
        joints = browser.evaluate("mocapdView.projectedJoints()")
        colour = browser.evaluate("mocapdView.skeletonColor")
        panels = browser.evaluate(
            "['hud', 'legend'].map((id) => { const r = document.getElementById(id).getBoundingClientRect();"
            " return [r.left, r.top, r.right, r.bottom]; })")
        png = browser.screenshot_png()
        with open(os.path.join(args.work, "live_view.png"), "wb") as f:
            f.write(png)
        inside, found, drawn = skeleton_pixels_found(png, joints, colour, panels)
        assert drawn > 0.01, f"the page looks blank ({drawn:.2%} of it drawn)"
        assert inside >= 10, f"only {inside} joints of actor1 are on screen and clear of the panels: {joints}"
        assert found >= 0.7 * inside, f"the skeleton's colour is at only {found} of {inside} joints"
        assert browser.evaluate("location.search") == "", "the token stayed in the address"
        m = metrics(daemon.http_port, token)
        sent = m.get(("mocapd_live_messages_sent_total", ()), 0)
        assert sent > 0, "the daemon sent no live-view message"
        print(f"LIVE VIEW: {args.subjects} actors; first frame {state['first']:.0f} ms after the page opened; "
              f"render {state['fps']:.1f} fps; {state['frames']} frames over the WebSocket; skeleton colour at "
              f"{found} of {inside} joints on screen; {drawn:.1%} of the page drawn; screenshot in {args.work}/live_view.png")
    finally:
        if browser is not None:
            browser.close()
        replay.kill()
        replay.wait()
        code = daemon.stop()
    assert code in (0, 3), daemon.read_log()
    print("live view browser test passed")


if __name__ == "__main__":
    main()
