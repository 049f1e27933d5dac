"""Reports of a localization: the overview plot (like the paper's Fig. 4) and the sensor GeoJSON."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fgloc.geo import pose_from_se3, transformer
from fgloc.labels import LEFT, NAMES, RIGHT, STRAIGHT
from fgloc.result import LocalizationResult

#: label -> (target colour, source colour); paper Fig. 4: blue left, red right, black straight
LABEL_COLOURS: dict[int, tuple[str, str]] = {
    STRAIGHT: ("#b8b8b8", "#000000"),
    LEFT: ("#9ecae1", "#1f4fd6"),
    RIGHT: ("#fcae91", "#d62728"),
}


def fov_polygon_local(
    T_local: np.ndarray, hfov_deg: float, max_range: float, n: int = 33
) -> np.ndarray:
    """(n+2, 2) closed outline of the horizontal field of view in L (sensor apex first)."""
    x, y, _, yaw, _, _ = pose_from_se3(T_local)
    half = math.radians(hfov_deg) / 2.0
    a = yaw + np.linspace(-half, half, n)
    arc = np.column_stack([x + max_range * np.cos(a), y + max_range * np.sin(a)])
    apex = np.array([[x, y]])
    return np.vstack([apex, arc, apex])


def sensor_geojson(res: LocalizationResult, hfov_deg: float, max_range: float) -> dict[str, Any]:
    """GeoJSON (RFC 7946, WGS84 lon/lat) with the sensor position and its field of view."""
    doc = res.to_json()
    to_wgs = transformer(res.crs, "EPSG:4326")
    fov_world = res.frame.to_world(fov_polygon_local(res.T_local, hfov_deg, max_range))
    lon, lat = to_wgs.transform(fov_world[:, 0], fov_world[:, 1])
    props = {
        "method": res.method,
        "crs": res.crs,
        "x": doc["sensor"]["x"],
        "y": doc["sensor"]["y"],
        "z": doc["sensor"]["z"],
        "yaw_deg": doc["sensor"]["yaw_deg"],
        "true_heading_deg": doc["true_heading_deg"],
        "converged": res.converged,
    }
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [doc["lon"], doc["lat"]]},
                "properties": {"kind": "sensor", **props},
            },
            {
                "type": "Feature",
                "geometry": {
                    "type": "Polygon",
                    "coordinates": [[[float(a), float(b)] for a, b in zip(lon, lat)]],
                },
                "properties": {
                    "kind": "field_of_view",
                    "hfov_deg": hfov_deg,
                    "max_range_m": max_range,
                },
            },
        ],
    }


def covariance_ellipse(cov_xy: np.ndarray, n_sigma: float = 3.0, n: int = 64) -> np.ndarray:
    """(n, 2) points of the n-sigma ellipse of a 2x2 covariance, centred at 0."""
    w, V = np.linalg.eigh(np.asarray(cov_xy, dtype=float))
    a = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.column_stack([np.cos(a), np.sin(a)])
    return n_sigma * circle * np.sqrt(np.maximum(w, 0.0)) @ V.T


def plot_overview(
    path: str,
    res: LocalizationResult,
    target_xyz: np.ndarray,
    target_label: np.ndarray,
    hfov_deg: float,
    max_range: float,
    true_T_local: np.ndarray | None = None,
) -> None:
    """Write the overview PNG: labelled target road points, labelled source points placed with
    the estimated pose, the sensor and its field of view (and the covariance ellipse, and the
    true sensor position when given). Axes are metres in the local frame L."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PathCollection

    fig, ax = plt.subplots(figsize=(9, 9), dpi=110)
    for code, (c_t, _) in LABEL_COLOURS.items():
        m = target_label == code
        if np.any(m):
            ax.scatter(
                target_xyz[m, 0],
                target_xyz[m, 1],
                s=1,
                c=c_t,
                lw=0,
                label=f"road ({NAMES[code]})",
                rasterized=True,
            )
    if res.source_xyz is not None and len(res.source_xyz):
        src_label = (
            res.source_label if res.source_label is not None else np.zeros(len(res.source_xyz))
        )
        for code, (_, c_s) in LABEL_COLOURS.items():
            m = src_label == code
            if np.any(m):
                ax.scatter(
                    res.source_xyz[m, 0],
                    res.source_xyz[m, 1],
                    s=2,
                    c=c_s,
                    lw=0,
                    label=f"radar ({NAMES[code]})",
                    rasterized=True,
                )
    fov = fov_polygon_local(res.T_local, hfov_deg, max_range)
    ax.plot(fov[:, 0], fov[:, 1], color="#2ca02c", lw=1, label="field of view")
    x, y = res.T_local[0, 3], res.T_local[1, 3]
    ax.plot([x], [y], marker="^", ms=10, color="#2ca02c", mec="k", label="sensor (estimate)")
    if res.covariance is not None:
        ell = covariance_ellipse(np.asarray(res.covariance)[:2, :2]) + [x, y]
        ax.plot(ell[:, 0], ell[:, 1], color="#9467bd", lw=1.2, label="3-sigma position")
    if true_T_local is not None:
        ax.plot(
            [true_T_local[0, 3]],
            [true_T_local[1, 3]],
            marker="x",
            ms=10,
            color="m",
            label="sensor (truth)",
        )
    ax.set_aspect("equal")
    ax.set_xlabel(f"E - {res.frame.origin[0]:.0f} [m]")
    ax.set_ylabel(f"N - {res.frame.origin[1]:.0f} [m]")
    doc = res.to_json()
    s = doc["sensor"]
    ax.set_title(
        f"fgloc {res.method}: E {s['x']:.2f}  N {s['y']:.2f}  yaw {s['yaw_deg']:.2f} deg"
        f"{'' if res.converged else '  (NOT CONVERGED)'}\n{res.crs}",
        fontsize=10,
    )
    legend = ax.legend(loc="upper right", fontsize=7)
    for handle in legend.legend_handles:  # scatter dots are tiny; enlarge them in the legend only
        if isinstance(handle, PathCollection):
            handle.set_sizes([20.0])
    ax.grid(True, lw=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
