"""Derives the robot models of r2pac_jax/envs/assets/bullet from the original Bullet-Safety-Gym
1.4.0 package (MIT License, Copyright (c) 2021 Sven Gronauer), so that the bullet backend loads
the original's physical numbers without the package:

    python benchmarks/fidelity_bullet/make_assets.py /path/to/bullet_safety_gym/envs/data

Each model keeps every inertial, joint, contact and collision element as written; visual
elements are dropped (in DIRECT mode they draw nothing, and pybullet computes inertia from
collision shapes, never from visuals: the fidelity tests check the result bit for bit), and the
collision meshes they reference are copied beside them.
"""
import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

OUT = Path(__file__).resolve().parents[2] / "r2pac_jax" / "envs" / "assets" / "bullet"
MODELS = {"robots/racecar/racecar_differential.urdf": "racecar_differential.urdf",
          "robots/quadcopter/quadcopter.urdf": "quadcopter.urdf"}


def strip(src: Path, dst: Path, origin: str) -> None:
    tree = ET.parse(src)
    root = tree.getroot()
    for link in root.iter("link"):
        for v in link.findall("visual"):
            link.remove(v)
    meshes = set()
    for m in root.iter("mesh"):
        meshes.add(m.get("filename"))
    for name in meshes:  # collision meshes, paths relative to the model
        target = dst.parent / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src.parent / name, target)
    text = ET.tostring(root, encoding="unicode")
    header = (f"<?xml version=\"1.0\" ?>\n<!-- Derived from Bullet-Safety-Gym 1.4.0 {origin} "
              "(MIT License, Copyright (c) 2021 Sven Gronauer) by benchmarks/fidelity_bullet/"
              "make_assets.py: visual elements removed, everything else as written. -->\n")
    dst.write_text(header + text + "\n")


if __name__ == "__main__":
    data = Path(sys.argv[1])
    for src, dst in MODELS.items():
        strip(data / src, OUT / dst, src)
        print(OUT / dst)
