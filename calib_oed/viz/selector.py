r"""The pose selector of the meshcat view: one design pose solid, the others faint.

The page gets (live and static alike) a slider *pose* in meshcat's *Open
Controls* panel, a list of the design poses at the top left (click a pose;
hover for its label: feasibility and joint values in degrees, or mm for
prismatic joints), and keys: → / ↓ / ``n`` next pose, ← / ↑ / ``p`` previous,
``Home`` / ``End`` first / last, ``a`` / ``Esc`` all poses at once (faint).
The selected pose's robot is opaque and its reflectors and beams are shown;
the other poses' robots stay faint (or hidden with ``ghosts=False``) and
their reflectors and beams are hidden ("all": every pose faint, every beam
shown). Capsules keep the visibility set in *Open Controls*; when the robot
is drawn by its capsules, they are what turns solid.

**How it reaches the browser.** meshcat's viewer has a ``set_control``
command (a GUI control whose callback is JavaScript, ``eval``'d by the
viewer); the meshcat server forwards and records only its five drawing
commands, so the control is sent as a ``set_property`` message of node
``calib_oed/design/selector`` whose payload is the ``set_control`` command:
the server stores it with that node and replays it to every browser that
connects and into the static page, where the viewer runs it by its payload
type. The script keeps its state in ``window.calibOedPoses``
(``selected``: pose index, -1 for all; ``select(k)``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from calib_oed.model.robot import joint_kind

#: Name of the slider in meshcat's controls panel.
CONTROL = "pose"

_SCRIPT = r"""(() => {
  const cfg = __CONFIG__;
  const V = window.viewer || this;
  const S = window.calibOedPoses = window.calibOedPoses || {};
  if (S.onKey) window.removeEventListener("keydown", S.onKey);
  Object.assign(S, {n: cfg.n, labels: cfg.labels, selected: cfg.initial});
  const find = (path) => {  // an existing scene node, or null (scene_tree.find would create it)
    let t = V.scene_tree;
    for (const p of path) { t = t.children[p]; if (t === undefined) return null; }
    return t;
  };
  const robots = () => {
    const t = find(cfg.root.concat(["robots", "<object>"]));
    return t && t.object.children.length === cfg.n ? t.object : null;
  };
  let panel = document.getElementById("calib-oed-poses");
  if (panel) panel.remove();
  panel = document.createElement("div");
  panel.id = "calib-oed-poses";
  panel.style.cssText = "position:absolute;left:8px;top:8px;z-index:10;width:250px;" +
    "background:rgba(255,255,255,0.9);font:12px sans-serif;padding:6px;border-radius:4px";
  const head = document.createElement("div");
  head.id = "calib-oed-pose-current";
  head.style.cssText = "font-weight:bold;margin-bottom:4px";
  const bar = document.createElement("div");
  const list = document.createElement("ol");
  list.start = 0;
  list.style.cssText = "max-height:40vh;overflow:auto;margin:4px 0 0 0;padding-left:34px;cursor:pointer";
  const button = (text, what, title) => {
    const b = document.createElement("button");
    b.textContent = text; b.title = title; b.onclick = what; bar.appendChild(b);
  };
  button("\u25c0", () => S.step(-1), "previous pose (\u2190)");
  button("all", () => S.select(-1), "all poses, faint (a)");
  button("\u25b6", () => S.step(1), "next pose (\u2192)");
  const hint = document.createElement("div");
  hint.textContent = "\u2190/\u2192 step, a: all; hover a pose for its joints";
  hint.style.cssText = "color:#555;font-size:11px;margin-top:3px";
  cfg.short.forEach((text, i) => {
    const li = document.createElement("li");
    li.textContent = text; li.title = cfg.labels[i]; li.dataset.pose = i;
    li.style.color = cfg.infeasible.includes(i) ? "#c00" : "#000";
    li.onclick = () => S.select(i);
    list.appendChild(li);
  });
  panel.append(head, bar, hint, list);
  document.body.appendChild(panel);
  const paint = (object, solid, i) => object.traverse((o) => {
    if (o.material) {
      o.material.color.setHex(solid ? cfg.solid[i] : cfg.faint[i][0]);
      o.material.opacity = solid ? 1 : cfg.faint[i][1];
      o.material.transparent = !solid;
      o.material.depthWrite = solid;
      o.material.needsUpdate = true;
    }
  });
  S.apply = () => {
    const k = S.selected, g = cfg.instanced ? robots() : null;
    for (let i = 0; i < cfg.n; i++) {
      const solid = k === i, shown = k < 0 || k === i;
      if (g) {
        g.children[i].visible = shown || cfg.ghosts;
        paint(g.children[i], solid, i);
      }
      const p = find(cfg.root.concat([cfg.names[i]]));
      if (p) {
        for (const part of ["beams", "reflectors"]) {
          if (p.children[part]) p.children[part].object.visible = shown;
        }
        if (!cfg.instanced) {
          p.object.visible = shown || cfg.ghosts;
          if (p.children.capsules) paint(p.children.capsules.object, solid, i);
        }
      }
      list.children[i].style.background = solid ? "#ffe08a" : "";
    }
    head.textContent = k < 0 ? `all ${cfg.n} poses` : cfg.labels[k];
    if (k >= 0) list.children[k].scrollIntoView({block: "nearest"});
    const c = V.gui_controllers && V.gui_controllers[cfg.control];
    if (c) { c.object[cfg.control] = k; c.updateDisplay(); }
    if (V.set_dirty) V.set_dirty();
    return g !== null || !cfg.instanced;
  };
  S.select = (k) => {
    S.selected = Math.max(-1, Math.min(cfg.n - 1, Math.round(k)));
    return S.apply();
  };
  S.step = (d) => S.select(S.selected < 0 ? (d > 0 ? 0 : cfg.n - 1) : (S.selected + d + cfg.n) % cfg.n);
  S.onKey = (e) => {
    if (e.target && ["INPUT", "TEXTAREA"].includes(e.target.tagName)) return;
    const k = e.key;
    if (k === "ArrowRight" || k === "ArrowDown" || k === "n") S.step(1);
    else if (k === "ArrowLeft" || k === "ArrowUp" || k === "p") S.step(-1);
    else if (k === "Home") S.select(0);
    else if (k === "End") S.select(cfg.n - 1);
    else if (k === "a" || k === "Escape") S.select(-1);
    else return;
    e.preventDefault();
  };
  window.addEventListener("keydown", S.onKey);
  let tries = 0;
  const wait = () => { if (!S.apply() && tries++ < 600) setTimeout(wait, 50); };  // meshes still loading
  wait();
  return (v) => S.select(v);
})()"""


def pose_labels(model: pin.Model, q: np.ndarray, infeasible: Sequence[int]) -> tuple[list[str], list[str]]:
    """Per design pose: a long label (feasibility, joints in degrees, or mm for prismatic joints)
    and a short one for the list."""
    prismatic = [joint_kind(model.joints[j]) == "prismatic" for j in range(1, model.njoints)]
    scale = np.where(prismatic, 1e3, np.degrees(1.0))
    unit = "mm" if all(prismatic) else "deg" if not any(prismatic) else "deg/mm"
    long, short = [], []
    for k, qk in enumerate(np.asarray(q, dtype=float)):
        state = "INFEASIBLE" if k in infeasible else "feasible"
        values = ", ".join(f"{v:.1f}" for v in qk * scale)
        long.append(f"pose {k} ({state}): q = ({values}) {unit}")
        short.append(f"pose {k}" + (" (infeasible)" if k in infeasible else ""))
    return long, short


def add_selector(vis, root: str, pose_names: Sequence[str], labels: Sequence[str], short: Sequence[str],
                 faint: Sequence[tuple[int, float]], solid: Sequence[int], infeasible: Sequence[int], *,
                 instanced: bool,
                 ghosts: bool = True, initial: int = 0) -> str:
    """Send the selector to meshcat (see the module text); the node that carries it.

    Args:
        vis: A ``meshcat.Visualizer`` at its root.
        root: The design's node (``calib_oed/design``): it holds ``robots``
            (:class:`~calib_oed.viz.instances.RobotInstances`) and one node per pose.
        pose_names: The per-pose nodes below ``root`` (``pose_000``, ...).
        labels, short: Long and short label of each pose (:func:`pose_labels`).
        faint: Colour ``0xRRGGBB`` and opacity of each pose when not selected.
        solid: Colour of each pose when selected (opaque).
        infeasible: Indices of infeasible poses (listed in red).
        instanced: Whether the robots are drawn in ``root/robots`` (else by the
            capsules of each pose node).
        ghosts: Unselected robots faint (else hidden).
        initial: Pose selected when the page opens (-1: all).
    """
    import umsgpack  # meshcat's own message encoding (a dependency of meshcat)

    path = f"/meshcat/{root}/selector"
    config = {"n": len(pose_names), "root": ["meshcat", *root.split("/")], "names": list(pose_names),
              "labels": list(labels), "short": list(short), "faint": [[int(c), float(o)] for c, o in faint],
              "solid": [int(c) for c in solid],
              "infeasible": [int(k) for k in infeasible], "ghosts": bool(ghosts), "initial": int(initial),
              "control": CONTROL, "instanced": bool(instanced)}
    command = {"type": "set_control", "name": CONTROL, "path": path,
               "callback": _SCRIPT.replace("__CONFIG__", json.dumps(config)),
               "value": int(initial), "min": -1, "max": max(len(pose_names) - 1, 0), "step": 1}
    socket = vis.window.zmq_socket
    socket.send_multipart([b"set_property", path.encode("utf-8"), umsgpack.packb(command)])
    socket.recv()
    return path
