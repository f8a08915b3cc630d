"""A large arm from a ROS-Industrial xacro: the KUKA KR 120 R2500 pro of ROS-Industrial's
``kuka_experimental`` (``kuka_kr120_support``), as the ``rtb-data`` wheel ships it
(``rtbdata/xacro/kuka_description``; a dev dependency, from PyPI).

The wheel keeps the support packages under other folder names (``kuka_kr120`` for
``kuka_kr120_support``) and without ``package.xml``; :func:`kr120_workspace` lays out a
workspace of links named as the packages, as a user's ``src/`` folder would be, so
``$(find kuka_kr120_support)`` and ``package://`` resolve through ``package_dirs``.
"""

from __future__ import annotations

from pathlib import Path

import yaml

#: Support package name -> folder in rtbdata/xacro/kuka_description.
PACKAGES = {"kuka_kr120_support": "kuka_kr120", "kuka_resources": "kuka_resources"}
XACRO = "kuka_kr120_support/urdf/kr120r2500pro.xacro"


def kr120_workspace(folder: Path) -> tuple[Path, Path]:
    """(the xacro file, the workspace folder) of the KR 120 R2500 pro, links made in ``folder``."""
    import rtbdata

    source = Path(rtbdata.__file__).parent / "xacro" / "kuka_description"
    ws = Path(folder) / "ws"
    ws.mkdir(parents=True, exist_ok=True)
    for package, name in PACKAGES.items():
        link = ws / package
        if not link.exists():
            link.symlink_to(source / name, target_is_directory=True)
    return ws / XACRO, ws


def kr120_scene_file(folder: Path) -> Path:
    """The ``fms_kr300`` cell (a KR 300 R2500 of the same reach and link lengths) with the
    KR 120 R2500 pro loaded from the xacro: a scene file in ``folder``."""
    from importlib import resources

    xacro, ws = kr120_workspace(folder)
    data = yaml.safe_load(resources.files("calib_oed.scene.shipped").joinpath("fms_kr300.yaml").read_text())
    robot = {k: v for k, v in data["robot"].items() if k not in ("name", "compliance")}
    data["robot"] = {"xacro": str(xacro), "package_dirs": [str(ws)], **robot}
    data["name"] = "fms_kr120_xacro"
    path = Path(folder) / "fms_kr120_xacro.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
