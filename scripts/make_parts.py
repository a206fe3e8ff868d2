"""Regenerate the parts in `parts/`: STL models written with numpy, G-code from real slicers.

Each model is a polygon (in the XZ plane) extruded along Y, so every mesh is closed and
manifold by construction. Each G-code file comes from one slicer command with every setting that
matters spelled out on the command line, so the file does not depend on a user's profile. The
commands are printed as they run; `parts/README.md` lists them.

    python scripts/make_parts.py [--only prism|t_support|cube_gyroid|cura_t_support] [--print]

Needs PrusaSlicer 2.5 (`apt-get install prusa-slicer`) and, for the Cura fixture, CuraEngine
4.13 with Cura's machine definitions (`apt-get install cura-engine cura`).
"""

from __future__ import annotations

import argparse
import os
import shlex
import struct
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np

PARTS = Path(__file__).resolve().parent.parent / "parts"

# --- meshes -------------------------------------------------------------------------------------


def _ear_clip(poly: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles (indices into `poly`, counter-clockwise) covering a simple CCW polygon."""
    idx = list(range(len(poly)))
    out: list[tuple[int, int, int]] = []

    def cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    while len(idx) > 3:
        for k in range(len(idx)):
            i, j, m = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i], poly[j], poly[m]
            if cross(a, b, c) <= 1e-12:  # reflex or collinear: not an ear
                continue
            inside = any(
                cross(a, b, poly[p]) >= 0
                and cross(b, c, poly[p]) >= 0
                and cross(c, a, poly[p]) >= 0
                for p in idx
                if p not in (i, j, m)
            )
            if not inside:
                out.append((i, j, m))
                idx.pop(k)
                break
        else:  # pragma: no cover - only for non-simple input
            raise ValueError("polygon is not simple")
    out.append((idx[0], idx[1], idx[2]))
    return out


def extrude_xz(profile: Sequence[tuple[float, float]], depth: float) -> np.ndarray:
    """A closed mesh (n x 3 x 3 triangles, outward normals) of an XZ profile extruded along Y.

    `profile` is a simple polygon, counter-clockwise seen from -Y (x to the right, z up).
    The solid spans ``0 <= y <= depth``.
    """
    p = np.asarray(profile, dtype=float)
    n = len(p)
    front = np.column_stack([p[:, 0], np.zeros(n), p[:, 1]])  # y = 0, seen from -Y
    back = front + [0.0, depth, 0.0]
    tris: list[np.ndarray] = []
    for i, j, k in _ear_clip(p):
        # Seen from -Y a CCW profile has its normal pointing to -Y (outward at y = 0):
        # x right, z up, viewer on -Y -> (x, z) CCW means normal -Y. Back face reversed.
        tris.append(np.array([front[i], front[k], front[j]]))
        tris.append(np.array([back[i], back[j], back[k]]))
    for i in range(n):
        j = (i + 1) % n
        tris.append(np.array([front[i], front[j], back[j]]))
        tris.append(np.array([front[i], back[j], back[i]]))
    mesh = np.array(tris)
    _orient_outward(mesh)
    return mesh


def _orient_outward(mesh: np.ndarray) -> None:
    """Flip every triangle so the mesh's signed volume is positive (normals point out)."""
    v = np.einsum("ij,ij->i", mesh[:, 0], np.cross(mesh[:, 1], mesh[:, 2])).sum() / 6.0
    if v < 0:
        mesh[:, [1, 2]] = mesh[:, [2, 1]]


def write_stl(path: Path, mesh: np.ndarray, name: str) -> None:
    """Write a binary STL (normals computed from the vertex order)."""
    normals = np.cross(mesh[:, 1] - mesh[:, 0], mesh[:, 2] - mesh[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    with path.open("wb") as f:
        f.write(name.encode("ascii")[:80].ljust(80, b" "))
        f.write(struct.pack("<I", len(mesh)))
        for nrm, tri in zip(normals, mesh, strict=True):
            f.write(struct.pack("<12fH", *nrm, *tri.ravel(), 0))


def box(w: float, d: float, h: float) -> np.ndarray:
    """A box w (x) by d (y) by h (z) mm."""
    return extrude_xz([(0, 0), (w, 0), (w, h), (0, h)], d)


def t_shape() -> np.ndarray:
    """A T, 40 mm wide and 25 mm high, 10 mm deep: a 10 mm stem under a 5 mm bar whose two
    15 mm arms overhang with nothing below them, so they need support material."""
    profile = [(15, 0), (25, 0), (25, 20), (40, 20), (40, 25), (0, 25), (0, 20), (15, 20)]
    return extrude_xz(profile, 10)


# --- slicing ------------------------------------------------------------------------------------

# A generic Marlin 2 printer (0.4 mm nozzle, 1.75 mm PLA). The firmware limits are emitted into
# the G-code (M201/M203/M204/M205), so the analysis reads them from the file itself.
PRUSA_PRINTER = [
    "--gcode-flavor", "marlin2",
    "--bed-shape", "0x0,250x0,250x210,0x210",
    "--nozzle-diameter", "0.4",
    "--filament-diameter", "1.75",
    "--temperature", "215", "--first-layer-temperature", "215",
    "--bed-temperature", "60", "--first-layer-bed-temperature", "60",
    "--start-gcode", "G28 ; home all axes\nG1 Z5 F5000 ; lift nozzle",
    "--end-gcode", "M104 S0\nM140 S0\nG28 X0\nM84",
    "--machine-limits-usage", "emit_to_gcode",
    "--machine-max-acceleration-x", "1000", "--machine-max-acceleration-y", "1000",
    "--machine-max-acceleration-z", "200", "--machine-max-acceleration-e", "5000",
    "--machine-max-acceleration-extruding", "1250",
    "--machine-max-acceleration-retracting", "1250",
    "--machine-max-acceleration-travel", "1250",
    "--machine-max-feedrate-x", "200", "--machine-max-feedrate-y", "200",
    "--machine-max-feedrate-z", "12", "--machine-max-feedrate-e", "120",
    "--machine-max-jerk-x", "8", "--machine-max-jerk-y", "8",
    "--machine-max-jerk-z", "0.4", "--machine-max-jerk-e", "4.5",
    "--default-acceleration", "1000", "--perimeter-acceleration", "800",
    "--infill-acceleration", "1250", "--bridge-acceleration", "1000",
    "--first-layer-acceleration", "500",
    "--retract-length", "0.8", "--retract-speed", "35", "--retract-lift", "0.2",
    "--skirts", "1", "--skirt-distance", "3", "--brim-width", "0",
]  # fmt: skip


PARTS_SPEC: dict[str, dict] = {
    # The paper's prism (case studies 1-2): 40 mm high, 20 mm wide, 2 mm deep. The paper prints
    # it in 20 minutes; these settings (0.22 mm layers, 3 perimeters, 30/20 mm/s walls, 6 s
    # minimum layer time) make PrusaSlicer estimate 19m 44s.
    "prism": {
        "mesh": lambda: box(20, 2, 40),
        "stl": "prism_40x20x2.stl",
        "gcode": "prism_40x20x2.gcode",
        "options": [
            "--layer-height", "0.22", "--first-layer-height", "0.2",
            "--perimeters", "3", "--top-solid-layers", "7", "--bottom-solid-layers", "5",
            "--fill-density", "20%", "--fill-pattern", "grid",
            "--perimeter-speed", "30", "--external-perimeter-speed", "20",
            "--small-perimeter-speed", "20", "--infill-speed", "40",
            "--solid-infill-speed", "30", "--top-solid-infill-speed", "20",
            "--gap-fill-speed", "20", "--travel-speed", "150", "--first-layer-speed", "20",
            "--slowdown-below-layer-time", "6", "--min-print-speed", "10",
        ],
    },
    # A T whose arms overhang 15 mm at 20 mm height: support material under both arms.
    "t_support": {
        "mesh": t_shape,
        "stl": "t_overhang.stl",
        "gcode": "t_overhang_support.gcode",
        "options": [
            "--layer-height", "0.2", "--first-layer-height", "0.2",
            "--perimeters", "2", "--top-solid-layers", "4", "--bottom-solid-layers", "3",
            "--fill-density", "15%", "--fill-pattern", "grid",
            "--support-material", "--support-material-auto",
            "--support-material-threshold", "0", "--support-material-pattern", "rectilinear",
            "--support-material-spacing", "2", "--support-material-interface-layers", "2",
            "--support-material-contact-distance", "0.2",
            "--perimeter-speed", "45", "--external-perimeter-speed", "30",
            "--infill-speed", "60", "--solid-infill-speed", "40", "--support-material-speed", "50",
            "--support-material-interface-speed", "100%", "--travel-speed", "150",
            "--first-layer-speed", "20",
        ],
    },
    # A 30 mm cube with 20% gyroid: most of its time is infill.
    "cube_gyroid": {
        "mesh": lambda: box(30, 30, 30),
        "stl": "cube_30.stl",
        "gcode": "cube_30_gyroid20.gcode",
        "options": [
            "--layer-height", "0.3", "--first-layer-height", "0.3",
            "--perimeters", "2", "--top-solid-layers", "4", "--bottom-solid-layers", "3",
            "--fill-density", "20%", "--fill-pattern", "gyroid",
            "--perimeter-speed", "45", "--external-perimeter-speed", "30",
            "--infill-speed", "80", "--solid-infill-speed", "50", "--top-solid-infill-speed", "30",
            "--travel-speed", "150", "--first-layer-speed", "20",
        ],
    },
}  # fmt: skip


def prusa_command(spec: dict) -> list[str]:
    return [
        "prusa-slicer",
        "--export-gcode",
        *PRUSA_PRINTER,
        *spec["options"],
        "--center", "125,105",
        "--output", f"parts/{spec['gcode']}",
        f"parts/{spec['stl']}",
    ]  # fmt: skip


# CuraEngine run from the command line uses each setting's `default_value` and evaluates none of
# the front end's formulas, so every derived setting that matters is given explicitly (e.g.
# infill_line_distance for 20 % grid, the support roof/bottom switches and speeds). The start
# G-code sets the firmware limits the engine's own estimate assumes (Cura's Marlin flavour does
# not emit M201/M203/M204/M205 by itself, but an Ender 3 profile's start code commonly does).
CURA_START = "\n".join(
    [
        "M201 X500 Y500 Z100 E5000 ; max acceleration",
        "M203 X500 Y500 Z10 E50 ; max feedrate",
        "M204 P500 R1000 T500 ; acceleration",
        "M205 X10 Y10 Z0.4 E5 ; jerk",
        "G28 ; home all axes",
        "G92 E0",
        "G1 Z2.0 F3000",
    ]
)
CURA_END = "\n".join(["G91", "G1 E-2 F2700", "G1 Z10", "G90", "M104 S0", "M140 S0", "M84"])
CURA_SETTINGS = {
    "machine_start_gcode": CURA_START, "machine_end_gcode": CURA_END,
    "machine_max_feedrate_x": 500, "machine_max_feedrate_y": 500,
    "machine_max_feedrate_z": 10, "machine_max_feedrate_e": 50,
    "machine_max_acceleration_x": 500, "machine_max_acceleration_y": 500,
    "machine_max_acceleration_z": 100, "machine_max_acceleration_e": 5000,
    "machine_acceleration": 500, "machine_max_jerk_xy": 10, "machine_max_jerk_z": 0.4,
    "machine_max_jerk_e": 5, "machine_minimum_feedrate": 0,
    "acceleration_enabled": "false", "jerk_enabled": "false",
    "layer_height": 0.2, "layer_height_0": 0.2, "wall_line_count": 2,
    "top_layers": 4, "bottom_layers": 3, "roofing_layer_count": 0,
    "infill_sparse_density": 20, "infill_pattern": "grid", "infill_line_distance": 4,
    "support_enable": "true", "support_type": "everywhere", "support_pattern": "lines",
    "support_line_distance": 2, "support_interface_enable": "true",
    "support_roof_enable": "true", "support_bottom_enable": "true",
    "speed_print": 50, "speed_wall_0": 25, "speed_wall_x": 40, "speed_infill": 50,
    "speed_topbottom": 30, "speed_support_infill": 50, "speed_support_roof": 40,
    "speed_support_bottom": 40, "speed_travel": 150, "speed_print_layer_0": 20,
    "speed_travel_layer_0": 100, "adhesion_type": "skirt",
}  # fmt: skip


def cura_command(resources: Path) -> list[str]:
    cmd = ["CuraEngine", "slice", "-j", str(resources / "definitions" / "creality_ender3.def.json")]
    for key, value in CURA_SETTINGS.items():
        cmd += ["-s", f"{key}={value}"]
    return cmd + ["-l", "parts/t_overhang.stl", "-o", "parts/t_overhang_cura.gcode"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=[*sorted(PARTS_SPEC), "cura_t_support"], action="append")
    ap.add_argument("--print", action="store_true", help="print the commands, run nothing")
    ap.add_argument(
        "--cura-resources",
        type=Path,
        default=Path("/usr/share/cura/resources"),
        help="Cura's resources folder (definitions/, extruders/) from Debian's `cura` package",
    )
    args = ap.parse_args()
    PARTS.mkdir(exist_ok=True)
    for name in args.only or [*sorted(PARTS_SPEC), "cura_t_support"]:
        env = None
        if name == "cura_t_support":
            res = args.cura_resources
            cmd = cura_command(res)
            # CuraEngine finds the definitions a machine inherits from through this variable.
            env = {**os.environ, "CURA_ENGINE_SEARCH_PATH": f"{res}/definitions:{res}/extruders"}
            print(f"CURA_ENGINE_SEARCH_PATH={res}/definitions:{res}/extruders " + shlex.join(cmd))
        else:
            spec = PARTS_SPEC[name]
            cmd = prusa_command(spec)
            print(shlex.join(cmd))
        if args.print:
            continue
        if name in PARTS_SPEC:
            write_stl(PARTS / PARTS_SPEC[name]["stl"], PARTS_SPEC[name]["mesh"](), name)
        subprocess.run(cmd, check=True, cwd=PARTS.parent, capture_output=True, env=env)


if __name__ == "__main__":
    main()
