"""The UAV's shape for ray casting, from the same dimensions as its JSBSim model.

Wing and tail sizes and the CG station are read from the aircraft XML
(``<metrics>``, ``<mass_balance>``); the fuselage and placement details JSBSim
has no element for come from ``aircraft/<name>/geometry.yaml``. The mesh is
in the body frame FRD with its origin at the CG, so posing it needs only the
JSBSim attitude and position.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import trimesh
import yaml

from fwsim import AIRCRAFT_DIR

_TO_M = {"M": 1.0, "FT": 0.3048, "IN": 0.0254}
_TO_M2 = {"M2": 1.0, "FT2": 0.3048**2}


@dataclass(frozen=True)
class AircraftGeometry:
    wingspan_m: float
    wing_area_m2: float
    chord_m: float
    htail_area_m2: float
    htail_arm_m: float
    vtail_area_m2: float
    vtail_arm_m: float
    cg_from_nose_m: float
    fuselage_length_m: float
    fuselage_diameter_m: float
    wing_leading_edge_from_nose_m: float
    wing_z_frd_m: float
    wing_thickness_m: float
    htail_aspect_ratio: float
    vtail_aspect_ratio: float
    tail_thickness_m: float


def _length(el) -> float:
    return float(el.text) * _TO_M[el.get("unit", "FT").upper()]


def load_geometry(name: str = "fwuav", aircraft_dir: Path = AIRCRAFT_DIR) -> AircraftGeometry:
    folder = Path(aircraft_dir) / name
    root = ET.parse(folder / f"{name}.xml").getroot()
    met = root.find("metrics")
    area = lambda tag: float(met.find(tag).text) * _TO_M2[met.find(tag).get("unit", "FT2").upper()]  # noqa: E731
    cg = root.find("mass_balance").find("location")
    cg_x = float(cg.find("x").text) * _TO_M[cg.get("unit", "IN").upper()]
    extra = yaml.safe_load((folder / "geometry.yaml").read_text())
    return AircraftGeometry(
        wingspan_m=_length(met.find("wingspan")), wing_area_m2=area("wingarea"), chord_m=_length(met.find("chord")),
        htail_area_m2=area("htailarea"), htail_arm_m=_length(met.find("htailarm")),
        vtail_area_m2=area("vtailarea"), vtail_arm_m=_length(met.find("vtailarm")),
        cg_from_nose_m=cg_x, **{k: float(v) for k, v in extra.items()})


def _box(x0, x1, y0, y1, z0, z1) -> trimesh.Trimesh:
    ext = [x1 - x0, y1 - y0, z1 - z0]
    T = np.eye(4)
    T[:3, 3] = [(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]
    return trimesh.creation.box(extents=ext, transform=T)


@lru_cache(maxsize=8)
def uav_mesh(name: str = "fwuav") -> trimesh.Trimesh:
    """Fuselage, wing and tail as one mesh in the body frame (FRD, origin at the CG).

    Each part is a closed convex solid; they are concatenated, not fused
    (ray casting only needs the first hit).
    """
    g = load_geometry(name)
    nose_x = g.cg_from_nose_m  # body x of the nose (x forward from the CG)
    r = g.fuselage_diameter_m / 2
    fus = trimesh.creation.cylinder(radius=r, height=g.fuselage_length_m, sections=16)
    T = trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0])  # cylinder axis z -> body x
    T[0, 3] = nose_x - g.fuselage_length_m / 2
    fus.apply_transform(T)
    le = nose_x - g.wing_leading_edge_from_nose_m
    half_span = g.wingspan_m / 2
    wing = _box(le - g.chord_m, le, -half_span, half_span,
                g.wing_z_frd_m - g.wing_thickness_m / 2, g.wing_z_frd_m + g.wing_thickness_m / 2)
    # tails: quarter chord at the tail arm behind the wing's quarter chord
    x_tail = le - 0.25 * g.chord_m - g.htail_arm_m
    h_span = math.sqrt(g.htail_area_m2 * g.htail_aspect_ratio)
    h_chord = g.htail_area_m2 / h_span
    htail = _box(x_tail - 0.75 * h_chord, x_tail + 0.25 * h_chord, -h_span / 2, h_span / 2,
                 -g.tail_thickness_m / 2, g.tail_thickness_m / 2)
    v_height = math.sqrt(g.vtail_area_m2 * g.vtail_aspect_ratio)
    v_chord = g.vtail_area_m2 / v_height
    xv = le - 0.25 * g.chord_m - g.vtail_arm_m
    vtail = _box(xv - 0.75 * v_chord, xv + 0.25 * v_chord, -g.tail_thickness_m / 2, g.tail_thickness_m / 2,
                 -r - v_height, -r + 0.01)
    return trimesh.util.concatenate([fus, wing, htail, vtail])
