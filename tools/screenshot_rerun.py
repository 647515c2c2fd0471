"""Screenshot the Rerun viewer replaying a run (the picture in docs/images/rerun_replay.png).

    python tools/screenshot_rerun.py                              # fly paper_mission, replay, shoot
    python tools/screenshot_rerun.py --log runs/x.mcap --t 120 --out shot.png

Flies the scenario (`fwsim run`, unless --log names a run's MCAP), exports it
(`fwsim replay`), starts the real viewer (`rerun --headless`, the binary of
rerun-sdk) on a free port, opens the .rrd through the viewer's control API
(`rerun.experimental.ViewerClient`), pauses the time cursor at --t, and saves
the viewer's own screenshot. The default layout is kept; for the picture the
time and selection panels are folded, the camera row is made taller and the
3D eye is put near the UAV and the ship at --t (the UAV drawn 25 times life
size, `fwsim replay --marker-scale 25`, so it shows at that distance).

No display is needed, but wgpu needs an adapter: without a GPU that is Mesa's
software Vulkan (Debian: `apt-get install mesa-vulkan-drivers`).
"""
from __future__ import annotations

import argparse
import io
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fwsim.interface import topics
ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _exe(name: str) -> str:
    p = BIN / name
    return str(p) if p.exists() else (shutil.which(name) or name)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _eye(log, t: float) -> tuple[list[float], list[float]] | None:
    """(eye position, look target) in ENU for the 3D view: the UAV and the ship at t, seen from the side."""
    tu, pu, _ = log.poses()
    if not len(tu) or not log.topics.get(topics.TARGET_STATE):
        return None
    ship = log.table(topics.TARGET_STATE)
    u = np.array([np.interp(t, tu, pu[:, k]) for k in range(3)])
    s = np.array([np.interp(t, ship["t_s"], ship["pos_enu_m"][:, k]) for k in range(3)])
    d = u - s
    d[2] = 0.0
    dist = max(float(np.linalg.norm(d)), 50.0)
    back = d / dist if np.linalg.norm(d) > 1 else np.array([0.0, -1.0, 0.0])
    side = np.array([-back[1], back[0], 0.0])
    look = 0.5 * (u + s)
    r = dist + 300.0  # from the side, a little behind and above: the UAV and the ship apart, the loiter behind
    eye = look + 0.4 * r * back + 1.4 * r * side + np.array([0.0, 0.0, 0.8 * r])
    return eye.round(1).tolist(), look.round(1).tolist()


def _tune_blueprint(bp: dict, eye: tuple[list[float], list[float]] | None) -> dict:
    views = {k: v["ViewBlueprint"] for k, v in bp.items() if "ViewBlueprint" in v}
    view3d = next((k for k, v in views.items() if v.get("class_identifier") == "3D"), None)
    view2d = next((k for k, v in views.items() if v.get("class_identifier") == "2D"), None)
    for c in bp.values():  # the column that holds the 3D view and the camera: a taller camera row
        cb = c.get("ContainerBlueprint", {})
        contents = ["/" + x for x in cb.get("contents", [])]
        if view3d in contents and view2d in contents and len(cb.get("row_shares", [])) == len(contents):
            cb["row_shares"] = [2.2 if x == view3d else 1.6 if x == view2d else 1.0 for x in contents]
    if view3d and eye:
        bp[f"{view3d}/EyeControls3D"] = {"EyeControls3D": {"position": eye[0], "look_target": eye[1],
                                                           "eye_up": [0.0, 0.0, 1.0]}}
    bp.setdefault("/time_panel", {}).setdefault("TimePanelBlueprint", {})["state"] = "Collapsed"
    bp["/selection_panel"] = {"PanelBlueprint": {"state": "Hidden"}}
    return bp


def shoot(rrd: Path, out: Path, t: float, size: str, eye, max_kb: int) -> None:
    from rerun.experimental import ViewerClient
    port = _free_port()
    cmd = [_exe("rerun"), "--headless", "--port", str(port), "--hide-welcome-screen", "--window-size", size]
    env = dict(os.environ, RUST_LOG=os.environ.get("RUST_LOG", "error"))
    errors = tempfile.TemporaryFile()
    # its own process group: bin/rerun is a wrapper whose child is the viewer, and both must go
    viewer = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=errors, start_new_session=True)
    try:
        client, err = None, None
        for _ in range(120):
            if viewer.poll() is not None:
                errors.seek(0)
                raise SystemExit(f"rerun exited ({viewer.returncode}): {errors.read().decode()[-2000:]}\n"
                                 "no graphics adapter? apt-get install mesa-vulkan-drivers")
            try:
                client = ViewerClient(f"rerun+http://127.0.0.1:{port}/proxy")
                client.get_state()
                break
            except Exception as e:  # noqa: BLE001 - not listening yet
                client, err = None, e
                time.sleep(0.5)
        if client is None:
            raise SystemExit(f"viewer on port {port} never answered: {err}")
        client.open(str(rrd))
        deadline = time.monotonic() + 120
        while client.get_state().loading and time.monotonic() < deadline:
            time.sleep(0.5)
        bp = client.get_blueprint()
        client.set_blueprint(_tune_blueprint(bp.blueprint, eye), store_id=bp.store_id)
        client.set_time("sim_time", duration=t, play_state="paused")
        time.sleep(2.0)
        client.take_screenshot()  # the first paint after the seek decodes the image; shoot the next
        time.sleep(1.0)
        png = client.take_screenshot()
    finally:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(viewer.pid, sig)
                viewer.wait(10)
                break
            except ProcessLookupError:
                break
            except subprocess.TimeoutExpired:
                continue
    out.parent.mkdir(parents=True, exist_ok=True)
    if len(png) > max_kb * 1024:  # recompress (lossless), then a 256-colour palette if still too big
        from PIL import Image
        img = Image.open(io.BytesIO(png)).convert("RGB")
        for im in (img, img.quantize(256, method=Image.Quantize.MEDIANCUT)):
            buf = io.BytesIO()
            im.save(buf, "PNG", optimize=True)
            png = buf.getvalue()
            if len(png) <= max_kb * 1024:
                break
    out.write_bytes(png)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(ROOT / "scenarios/paper_mission.yaml"))
    ap.add_argument("--log", help="a run's MCAP (default: fly --scenario)")
    ap.add_argument("--rrd", help="use this recording of --log instead of exporting one")
    ap.add_argument("--marker-scale", type=float, default=25.0,
                    help="fwsim replay's UAV drawing scale (default 25, so the UAV shows at this distance)")
    ap.add_argument("--t", type=float, help="sim time of the picture, s (default: 7 s before the run's end)")
    ap.add_argument("--out", default=str(ROOT / "docs/images/rerun_replay.png"))
    ap.add_argument("--size", default="1600x1000", help="viewer size in points (default 1600x1000)")
    ap.add_argument("--max-kb", type=int, default=600,
                    help="above this size, recompress the PNG, then cut it to 256 colours (default 600)")
    ap.add_argument("--workdir", help="where the log and .rrd go (default: a temporary folder)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="rerun_shot_") as tmp:
        work = Path(args.workdir or tmp)
        work.mkdir(parents=True, exist_ok=True)
        log = Path(args.log) if args.log else work / "run.mcap"
        if not args.log:
            rc = subprocess.run([_exe("fwsim"), "run", args.scenario, "--log", str(log), "--quiet"]).returncode
            if rc:
                return rc
        rrd = Path(args.rrd) if args.rrd else work / "run.rrd"
        if not args.rrd:
            r = subprocess.run([_exe("fwsim"), "replay", str(log), "--rrd", str(rrd),
                                "--marker-scale", str(args.marker_scale)], capture_output=True, text=True)
            if r.returncode:
                print(r.stdout + r.stderr, file=sys.stderr)
                return r.returncode
        from fwsim.log.reader import read_log
        run = read_log(log)
        t = args.t if args.t is not None else max(0.0, float(run.poses()[0][-1]) - 7.0)
        shoot(rrd, Path(args.out), t, args.size, _eye(run, t), args.max_kb)
    print(f"{args.out}: t = {t:.1f} s, {Path(args.out).stat().st_size // 1024} KiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
