"""The Foxglove layout written beside each run log (``layout.json``, app-export JSON: Layouts ->
Import from file): a Map panel over the geographic topics, the 3D scene, one Image panel per
camera and plots of errors, controller, motors and the spray job."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def _plot_cfg(title: str, paths: list[tuple[str, str]]) -> dict[str, Any]:
    return {
        "title": title,
        "paths": [{"value": v, "enabled": True, "timestampMethod": "receiveTime", "label": lbl}
                  for v, lbl in paths],
        "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True,
        "legendDisplay": "floating", "showPlotValuesInLegend": False, "isSynced": True,
        "xAxisVal": "timestamp", "sidebarDimension": 240,
    }


#: the Map panel's look per geographic topic: line colour (LocationFix topics; a GNSS fix is
#: drawn in its fix type's colour, :data:`ag_uav.record.geo.FIX_COLORS`) and which messages it
#: shows (``all`` the whole track, ``none`` the latest at the playback time)
_MAP_TOPICS = {
    "/geo/true": ({"historyMode": "all", "pointDisplayMode": "dot", "pointSize": 3},
                  "#ffffff"),
    "/geo/est": ({"historyMode": "all", "pointDisplayMode": "dot", "pointSize": 3}, "#4169e1"),
    "/geo/gnss": ({"historyMode": "all", "pointDisplayMode": "cross", "pointSize": 5}, None),
    "/geo/field": ({"historyMode": "all"}, None),
    "/geo/plan": ({"historyMode": "all"}, None),
    "/geo/sprayed": ({"historyMode": "none"}, None),
    "/geo/dose": ({"historyMode": "none"}, None),
}


def _map_cfg(geo: tuple[str, ...]) -> dict[str, Any]:
    """Foxglove's Map panel (``foxglove.layouts.MapConfig``'s keys) over the satellite layer,
    following the true position, naming only the geographic topics ``geo`` the log holds."""
    topics = [t for t in _MAP_TOPICS if t in geo]
    colors = {t: _MAP_TOPICS[t][1] for t in topics if _MAP_TOPICS[t][1]}
    return {"layer": "satellite", "zoomLevel": 18, "maxNativeZoom": 18,
            "followTopic": "/geo/true" if "/geo/true" in topics else "",
            "disabledTopics": [], "topicColors": colors,
            "topicConfig": {t: dict(_MAP_TOPICS[t][0], order=k) for k, t in enumerate(topics)}}


def write_foxglove_layout(
    path: str | Path,
    *,
    cameras: tuple[str, ...] | list[str] = ("chase", "down"),
    estimators: tuple[str, ...] | list[str] = (),
    ctrl_keys: tuple[str, ...] | list[str] = (),
    n_motors: int = 4,
    center: tuple[float, float] = (0.0, 0.0),
    spray: bool = False,
    geo: tuple[str, ...] | list[str] = (),
) -> Path:
    """Write a Foxglove layout in app-export JSON (import with Layouts -> Import from file).

    With ``geo`` (the run's geographic topics, :mod:`ag_uav.record.geo`) a Map panel first
    (:func:`_map_cfg`), then a 3D panel (field, plan, sprayed area, true/estimated/reference
    poses, GPS fixes, world frame), one Image panel per camera, and plots: tracking and
    estimation errors, controller outputs (``ctrl_keys`` ending in ``.u`` / ``.U`` first, up to
    8), motor commands.
    """
    cfg: dict[str, Any] = {}
    if geo:
        cfg["Map!aguavmap"] = _map_cfg(tuple(geo))
    cfg["3D!aguav3d"] = _scene3d_cfg(cameras, center)
    for c in cameras:
        cfg[f"Image!cam{c}"] = {
            "cameraState": {}, "followMode": "follow-pose", "scene": {}, "transforms": {},
            "topics": {}, "layers": {}, "publish": {}, "imageMode": {
                "imageTopic": f"/camera/{c}", "calibrationTopic": f"/camera/{c}/calibration"},
        }
    plots = _plot_panels(cfg, estimators, ctrl_keys, n_motors, spray)
    cams = [f"Image!cam{c}" for c in cameras]
    top: Any = "3D!aguav3d"
    if geo:  # the map first, beside the 3D scene
        top = {"direction": "row", "first": "Map!aguavmap", "second": top,
               "splitPercentage": 50}
    left = _chain([top, _chain(cams, "row")], "column") if cams else top
    if isinstance(left, dict):
        left["splitPercentage"] = 62
    right = _chain(plots, "column")
    layout = {
        "configById": cfg,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": {"direction": "row", "first": left, "second": right, "splitPercentage": 58},
    }
    from .atomic import atomic_write_text

    return atomic_write_text(path, json.dumps(layout, indent=1), fsync=False)


def _chain(items: list[Any], direction: str) -> Any:
    """Panels side by side (``row``) or stacked (``column``) in equal shares."""
    if len(items) == 1:
        return items[0]
    return {"direction": direction, "first": items[0],
            "second": _chain(items[1:], direction),
            "splitPercentage": 100.0 / len(items)}


def _scene3d_cfg(cameras: tuple[str, ...] | list[str],
                 center: tuple[float, float]) -> dict[str, Any]:
    """The 3D panel: field, plan, sprayed area, true/estimated/reference poses, GPS fixes."""
    return {
        "cameraState": {"distance": 80, "perspective": True, "phi": 55, "thetaOffset": 35,
                        "targetOffset": [center[0], center[1], 0], "target": [0, 0, 0],
                        "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.5,
                        "far": 5000},
        "followMode": "follow-none",
        "followTf": "world",
        "scene": {"transforms": {"showLabel": False, "axisScale": 1.5}},
        "transforms": {},
        "topics": {
            "/field": {"visible": True},
            "/sprayed": {"visible": True},
            "/drone/pose": {"visible": True, "type": "arrow", "color": "#ffffffff",
                            "arrowScale": [1.5, 0.25, 0.25]},
            "/drone/pose_est": {"visible": True, "type": "arrow", "color": "#4169e1ff",
                                "arrowScale": [1.2, 0.2, 0.2]},
            "/drone/pose_ref": {"visible": True, "type": "arrow", "color": "#22cc44ff",
                                "arrowScale": [1.0, 0.15, 0.15]},
            "/gps": {"visible": True, "type": "axis", "axisScale": 0.3},
            **{f"/camera/{c}": {"visible": False} for c in cameras},
        },
        "layers": {"grid": {"visible": True, "layerId": "foxglove.Grid", "frameId": "world",
                            "size": 200, "divisions": 40, "lineWidth": 1,
                            "color": "#248eff33", "position": [center[0], center[1], -0.05],
                            "rotation": [0, 0, 0], "order": 1}},
        "publish": {"type": "point"},
        "imageMode": {},
    }


def _plot_panels(cfg: dict[str, Any], estimators: tuple[str, ...] | list[str],
                 ctrl_keys: tuple[str, ...] | list[str], n_motors: int,
                 spray: bool) -> list[str]:
    """Add the plot panels to ``cfg``; their ids, top to bottom."""
    err_paths = [("/drone/state.err.horiz", "tracking error (horiz) [m]"),
                 ("/drone/state.err.z", "tracking error z [m]"),
                 ("/drone/state.est_err.horiz", "in-loop estimate error [m]")]
    err_paths += [(f"/estimator/{e}.err.horiz", f"{e} error [m]") for e in estimators]
    cfg["Plot!errors"] = _plot_cfg("errors", err_paths)
    keys = sorted(ctrl_keys, key=lambda k: (not k.lower().endswith((".u",)), k))[:8]
    cfg["Plot!ctrl"] = _plot_cfg("controller", [(f"/drone/state.ctrl.{k}", k) for k in keys]
                                 or [("/drone/state.speed", "speed [m/s]")])
    cfg["Plot!motors"] = _plot_cfg("motors", [(f"/drone/state.motors[{i}]", f"motor {i}")
                                              for i in range(n_motors)])
    cfg["Plot!pos"] = _plot_cfg("position vs reference", [
        ("/drone/state.pos.x", "x"), ("/drone/state.ref.x", "x ref"),
        ("/drone/state.pos.y", "y"), ("/drone/state.ref.y", "y ref"),
        ("/drone/state.pos.z", "z"), ("/drone/state.ref.z", "z ref")])
    plots = ["Plot!errors", "Plot!pos", "Plot!ctrl", "Plot!motors"]
    if spray:  # spray job (ag_uav.world.spray_job): tank, mass, battery
        cfg["Plot!spray"] = _plot_cfg("spray job", [
            ("/drone/spray.tank_l", "tank [L]"), ("/drone/spray.mass_kg", "mass [kg]"),
            ("/drone/spray.battery_frac", "battery left"), ("/drone/spray.sortie", "sortie")])
        plots.append("Plot!spray")
    return plots
