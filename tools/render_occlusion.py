"""Render the wing hiding the ship: the same pose at three bank angles, side by side.

The UAV flies south with the ship abeam on its left; the gimbal is pointed at
the ship. Banking toward the ship lifts it above the wing plane: first the wing
edge cuts the box, then the ship is gone (still inside the field of view).

    python tools/render_occlusion.py --out docs/images/occlusion.png
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np

from fwsim.sensors.camera import Camera, CameraConfig, Pose, RenderConfig
from fwsim.interface.frames import dcm_enu_from_frd
from fwsim.world.geometry import uav_mesh
from fwsim.world.gimbal import camera_pose_world, pan_tilt_pointing_at
from fwsim.world.target import Ship, TargetConfig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--banks", type=float, nargs="+", default=[0.0, -29.0, -35.0])
    ap.add_argument("--range-m", type=float, default=300.0)
    ap.add_argument("--height-m", type=float, default=120.0)
    args = ap.parse_args(argv)
    ship = Ship(TargetConfig())
    cfg = CameraConfig(hfov_deg=40.0, render=RenderConfig(width_px=480, height_px=270))
    cam = Camera(cfg, uav_mesh("fwuav"), ship.mesh)
    pos_ship, R_ship = ship.pose(0.0)
    ship_pose = Pose(R_ship, pos_ship)
    mount = np.array(cfg.gimbal.mount_offset_frd_m)
    pos = np.array([-args.range_m, 0.0, args.height_m])
    panels = []
    for bank in args.banks:
        euler = np.array([math.radians(bank), 0.03, math.pi])
        R = dcm_enu_from_frd(euler)
        pan, tilt = pan_tilt_pointing_at(R.T @ (np.array([0.0, 0.0, 8.0]) - (pos + R @ mount)))
        cp, Rc = camera_pose_world(pos, euler, mount, pan, tilt)
        det = cam.detect(0.0, cp, Rc, Pose(R, pos), ship_pose)
        img = cam.render(cp, Rc, Pose(R, pos), ship_pose, det.bbox_px if det.visible_px else None)
        occ = det.occluded_fraction
        label = f"bank {bank:+.0f} deg, tilt {math.degrees(tilt):+.0f} deg: {100 * occ:.0f} % hidden"
        cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        panels.append(img)
        print(label)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, np.hstack(panels))
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
