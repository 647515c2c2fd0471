"""The departure ablation: each of fwsim's departures from the paper switched off alone, and all of them.

Every variant flies the paper mission and the terminal sweep (scenarios/batches/terminal_sweep.yaml), as one
``fwsim.batch.runner`` of ``1 + 42`` runs per variant, and the tool prints a Markdown table (docs/design/departures.md's):

    python tools/ablation.py --workers 2 --out runs/ablation           # ~25 min on 2 cores
    python tools/ablation.py --only endgame,bias_cap                  # some rows only
    python tools/ablation.py --resume --out runs/ablation             # fly only what is missing

Columns: the paper mission's hit, miss and impact-angle errors and its worst UKF error after convergence
(seed 7), then the sweep's cases within 3 m / 3 deg, hits, median miss and worst impact-angle error (seed 1).
``all off`` is scenarios/paper_as_printed.yaml's set of switches.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import yaml

from fwsim import SCENARIO_DIR
from fwsim.batch.runner import run_batch
from fwsim.batch.cases import SWEEP_SPEC, sweep_rows

#: name -> (what it is, the overrides that switch it off)
DEPARTURES: dict[str, tuple[str, dict]] = {
    "nmpc_solve_ahead": ("the NMPC solved ahead (0.067 s), in a worker process",
                         {"controllers.nmpc.solve_ahead_s": 0.0}),
    "box_centre_correction": ("box-centre correction for the ship's shape",
                              {"controllers.target_model.enabled": False}),
    "heading_from_shapes": ("a still ship's heading from its box shapes",
                            {"controllers.target_model.heading_from_shape.enabled": False}),
    "shapes_follow_course": ("the box shapes' heading turns with the estimated course",
                             {"controllers.target_model.heading_from_shape.follow_course": False}),
    "size_fit": ("the ship's length, beam and height fitted to its boxes",
                 {"controllers.target_model.size_fit.enabled": False}),
    "detection_gates": ("detection gates (overflowing box, size mismatch, inside 120 m)",
                        {"controllers.detection_gate.skip_overflowing_box": False,
                         "controllers.detection_gate.box_size_tolerance": 10.0,
                         "controllers.detection_gate.min_range_m": 0.0}),
    "own_box_headings": ("a box off in size corrected over its own headings when the airframe cannot have cut it",
                         {"controllers.detection_gate.size_mismatch_action": "skip"}),
    "class_check_clear_only": ("the class check counts only boxes the airframe cannot have cut",
                               {"controllers.detection_gate.class_check_clear_only": False}),
    "maybe_cut_deweight": ("a box off in size that may be cut used with its doubt, not skipped",
                           {"controllers.detection_gate.maybe_cut_action": "skip"}),
    "stall_go_around": ("a dive that holds its range for 20 s goes round",
                        {"controllers.switch.go_around_stall_s": None}),
    "layout_fit": ("the end the superstructure stands at learnt from where the box centres fall",
                   {"controllers.target_model.layout_fit.enabled": False}),
    "moving_gate": ("a moving ship's boxes taken down to 80 m (a still one's to 120 m)",
                    {"controllers.detection_gate.moving_min_range_m": 120.0}),
    "innovation_gate": ("the UKF's chi-square innovation gate", {"controllers.ukf.innovation_gate": 0.0}),
    "plane_height": ("the UKF's plane at the box centre's height (3.75 m; paper: the sea)",
                     {"controllers.ukf.target_plane_height_m": 0.0}),
    "position_propagation": ("own position propagated between GNSS fixes (and the gyro-turned velocity)",
                             {"controllers.navigation.propagate": False}),
    "gyro_turned_velocity": ("the GNSS velocity turned with the gyros between fixes",
                             {"controllers.navigation.turn_velocity": False}),
    "keyhole_swing": ("IBVS keyhole swing through the pan axis", {"controllers.ibvs.keyhole_swing": False}),
    "reacquisition": ("pointing at the estimate when the ship is lost",
                      {"controllers.reacquire.after_s": 60.0, "controllers.reacquire.search_after_s": 3600.0}),
    "approach_rate": ("the NMPC's approach-rate term f5 (no head-on entry, no full-bank loops)",
                      {"controllers.nmpc.w5_approach": 0.0}),
    "air_relative": ("the NMPC predicts the target in the air mass (minus the wind estimate)",
                     {"controllers.nmpc.air_relative": False}),
    "contact_aim": ("BPNG steers to the hull's surface, not the aim point", {"controllers.bpng.aim_at_contact": False}),
    "bias_cap": ("BPNG's bias term capped at 90 deg", {"controllers.bpng.bias_angle_cap_deg": None}),
    "capture_guard": ("BPNG's capture guard (3 deg/s toward the ship far off the nose)",
                      {"controllers.bpng.capture_turn_deg_s": None}),
    "endgame": ("angle-hold endgame for the last 0.4 s", {"controllers.bpng.endgame_tgo_s": 0.0}),
}


def all_off() -> dict:
    """Every departure switched off at once (what scenarios/paper_as_printed.yaml flies)."""
    out = {}
    for _, overrides in DEPARTURES.values():
        out.update(overrides)
    return out


def spec(names: list[str], out_dir: Path) -> Path:
    """One batch spec: for each variant, the paper mission and the sweep's cases, with its overrides."""
    sweep = yaml.safe_load(SWEEP_SPEC.read_text())["runs"][0]
    runs = []
    for name in names:
        overrides = {} if name == "fwsim" else all_off() if name == "all_off" else DEPARTURES[name][1]
        tag = {"set": {**overrides, "description": f"ablation: {name}"}}
        runs.append({"scenario": str(SCENARIO_DIR / "paper_mission.yaml"), **tag})
        runs.append({**sweep, **tag})
    path = out_dir / "ablation.yaml"
    out_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({"name": "ablation", "runs": runs}, sort_keys=False))
    return path


def _f(x, fmt="{:.2f}") -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)


def table(rows: list[dict], names: list[str]) -> str:
    lines = ["| switched off | paper mission: hit, miss m, fpa / heading err deg, UKF max m | "
             "sweep: within 3 m / 3° | hits | median miss m | worst angle err deg |",
             "|---|---|---|---|---|---|"]
    for name in names:
        mine = [r for r in rows if r.get("set.description") == f"ablation: {name}"]
        paper = [r for r in mine if r["scenario"] == "paper_mission"]
        cases = sweep_rows([r for r in mine if r["scenario"] != "paper_mission"])
        label = {"fwsim": "nothing (fwsim as it is)", "all_off": "all of them (paper_as_printed)"}.get(
            name, DEPARTURES.get(name, (name,))[0])
        p = paper[0] if paper else {}
        cell = (f"{'hit' if p.get('hit') == 1.0 else 'MISS'}, {_f(p.get('miss_distance_m'))}, "
                f"{_f(p.get('impact_fpa_error_deg'), '{:+.2f}')} / {_f(p.get('impact_heading_error_deg'), '{:+.2f}')}, "
                f"{_f(p.get('estimator_pos_err_max_after_convergence_m'), '{:.1f}')}") if p else "—"
        miss = [c["miss_distance_m"] for c in cases if math.isfinite(c["miss_distance_m"])]
        ang = [max(abs(c["impact_fpa_error_deg"]), abs(c["impact_heading_error_deg"])) for c in cases
               if math.isfinite(c["impact_fpa_error_deg"])]
        lines.append(f"| {label} | {cell} | {sum(c['ok'] for c in cases)}/{len(cases)} | "
                     f"{sum(c['hit'] == 1.0 for c in cases)}/{len(cases)} | "
                     f"{_f(float(np.median(miss)) if miss else None)} | {_f(max(ang) if ang else None, '{:.1f}')} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="runs/ablation")
    ap.add_argument("--only", help="comma-separated variants (default: fwsim, every departure, all_off)")
    ap.add_argument("--resume", action="store_true", help="keep the runs already flown in --out")
    args = ap.parse_args(argv)
    names = ["fwsim", *DEPARTURES, "all_off"]
    if args.only:
        names = [n for n in args.only.split(",") if n]
        bad = [n for n in names if n not in ("fwsim", "all_off", *DEPARTURES)]
        if bad:
            print(f"error: --only: unknown variant {bad[0]!r} (known: fwsim, all_off, {', '.join(DEPARTURES)})",
                  file=sys.stderr)
            return 2
    out = Path(args.out)
    done = [0]

    def progress(row):
        done[0] += 1
        print(f"{done[0]:4d} {row['status']:9s} {row['id']}", flush=True)

    result = run_batch(spec(names, out), out, workers=args.workers, resume=args.resume, on_row=progress)
    text = table(result.rows, names)
    (out / "ablation.md").write_text(text + "\n")
    print(text)
    print(out / "ablation.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
