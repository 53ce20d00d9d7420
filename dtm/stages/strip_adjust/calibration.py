"""The ``strip_adjust`` stage with ``model: mounting``: read, link, solve, re-georeference (issue 23).

The algorithm is :mod:`dtm.stages.strip_adjust.mounting`.  This driver rebuilds the
trajectory exactly as the georeference stage does, finds for every point of
``points_georef`` its pulse (the georeference stage writes the pulses that
have a trajectory and a strip in pulse order, and whether a pulse is kept
depends on its time alone), estimates the corrections from the single
returns of the strips, and writes the points again through the full
georeferencing equation with the corrected mounting.
"""

from __future__ import annotations

import numpy as np

from dtm.common.georeferencing import LAS_GPS_OFFSET  # how the georeference stage writes gps_time
from dtm.stages.strip_adjust.mounting import ADVICE, Links, Sample, corrected_mounting, distances, make_unknowns, solve
from pipeline.errors import ConfigError, InputDataError


def pulse_index(pulse_time: np.ndarray, las_time: np.ndarray) -> np.ndarray:
    """For each point of the georeferenced LAS, the index of its pulse.

    The LAS holds a subsequence of the pulses, in their order, and a pulse time is either kept with all
    its echoes or dropped with them, so the k-th point of a run of equal times is the k-th pulse of
    that time.

    >>> pulse_index(np.array([1e9 + 1, 1e9 + 2, 1e9 + 2, 1e9 + 3]), np.array([2.0, 2.0, 3.0])).tolist()
    [1, 2, 3]
    """
    tp = np.asarray(pulse_time, dtype=np.float64) - LAS_GPS_OFFSET
    tl = np.asarray(las_time, dtype=np.float64)
    if len(tl) == 0:
        return np.zeros(0, np.int64)
    if np.any(np.diff(tp) < 0):
        raise InputDataError("stages.strip_adjust.model: mounting needs the pulses in time order, and these are not.")
    new = np.concatenate(([True], tl[1:] != tl[:-1]))
    starts = np.flatnonzero(new)
    rank = np.arange(len(tl)) - starts[np.cumsum(new) - 1]
    idx = np.searchsorted(tp, tl, side="left") + rank
    ok = idx < len(tp)
    if not ok.all() or not np.array_equal(tp[idx], tl):
        raise RuntimeError("the georeferenced points do not correspond to the parsed pulses (cache out of step?)")
    return idx


def _read_points(path):
    """gps_time, strip and whether it is a single return, of every point (11 bytes a point)."""
    import laspy

    parts = {k: [] for k in ("t", "sid", "single")}
    with laspy.open(str(path)) as reader:
        for chunk in reader.chunk_iterator(1_000_000):
            parts["t"].append(np.asarray(chunk.gps_time, dtype=np.float64))
            parts["sid"].append(np.asarray(chunk.point_source_id).astype(np.uint16))
            parts["single"].append(np.asarray(chunk.number_of_returns) <= 1)
    if not parts["t"]:
        return np.zeros(0), np.zeros(0, np.uint16), np.zeros(0, bool)
    return tuple(np.concatenate(parts[k]) for k in ("t", "sid", "single"))


class _Geometry:
    """The trajectory, mounting and map transform of the georeference stage, rebuilt."""

    def __init__(self, ctx, traj, tmeta, pulses, pmeta):
        from dtm.common.crs import output_crs
        from dtm.common.georeferencing import exact_output, ltp_output, prepare_exact, prepare_ltp, pulse_reach

        g = ctx.setting("stages.georeference")
        convention = tmeta["convention"]
        lat0, lon0 = float(traj["lat"][0]), float(traj["lon"][0])
        self.exact, self.mounting = prepare_exact(traj, convention, pmeta)
        reach = pulse_reach(pulses["x"], pulses["y"], pulses["z"])
        reach += float(np.linalg.norm(self.mounting.lever_arm)) + 11.0
        if g.frame == "exact":
            crs = output_crs(ctx.setting("crs"), None, (lon0, lat0))
            out = exact_output(self.exact, crs, reach, geoid=g.geoid)
        else:
            out = ltp_output(prepare_ltp(traj, convention, lat0, lon0, g.ltp_radius_m), g.ltp_radius_m, reach)
        self.output = out.trajectory
        self.to_map = out.columns

    def map_to_local(self, xyz: np.ndarray) -> np.ndarray:
        """Output-CRS coordinates -> the output trajectory's local frame (Newton on the map transform)."""
        local = np.asarray(xyz, dtype=np.float64).copy()
        centre = self.output.position.mean(axis=0)
        guess = np.tile(centre, (len(local), 1))
        for _ in range(6):
            m0 = np.column_stack(self.to_map(*guess.T))
            jac = np.empty((len(guess), 3, 3))
            for k in range(3):
                step = guess.copy()
                step[:, k] += 1.0
                jac[:, :, k] = np.column_stack(self.to_map(*step.T)) - m0
            guess = guess + np.linalg.solve(jac, (local - m0)[:, :, None])[:, :, 0]
        return guess


def _link_finder(sample: Sample, strips: list[int], p, control_local):
    """The closure :func:`dtm.stages.strip_adjust.mounting.solve` calls in each round: patches, matches, control."""
    from scipy.spatial import cKDTree

    from dtm.stages.strip_adjust.icp import Transform, match, patch_points, planar_patches

    def find(xyz: np.ndarray):
        patches = {}
        for s in strips:
            sel = np.flatnonzero(sample.strip == s)
            patches[s] = planar_patches(xyz[sel], cell=p.cell, min_points=p.min_points, max_rms=p.max_plane_rms)
            patches[s].order = sel[patches[s].order]
        all_rms = np.concatenate([patches[s].rms for s in strips]) if strips else np.zeros(0)
        if not len(all_rms):
            return None
        limit = min(p.max_plane_rms, 2.5 * float(np.median(all_rms)))
        for s in strips:  # smooth and well sampled, as for the rigid model
            dense = patches[s].count >= 0.5 * np.median(patches[s].count) if len(patches[s].count) else True
            patches[s].keep((patches[s].rms <= limit) & dense)
        ident = Transform(np.zeros(3))
        parts = {k: [] for k in ("surf", "sg", "obs", "og", "origin", "strips", "weight", "rms", "fixed", "fg")}
        k = 0
        for i, a in enumerate(strips):
            for b in strips[i + 1 :]:
                ia, ib = match(patches[a], ident, patches[b], ident, max_distance=p.max_distance)
                if not len(ia):
                    continue
                sa, ga = patch_points(patches[a], ia)
                sb, gb = patch_points(patches[b], ib)
                parts["surf"].append(sa)
                parts["sg"].append(ga + k)
                parts["obs"].append(sb)
                parts["og"].append(gb + k)
                parts["origin"].append(patches[a].origin[ia])
                parts["strips"].append(np.tile([a, b], (len(ia), 1)))
                parts["weight"].append(patches[b].count[ib].astype(np.float64))
                parts["rms"].append(np.hypot(patches[a].rms[ia], patches[b].rms[ib]))
                k += len(ia)
        if control_local is not None and len(control_local):
            for s in strips:
                if not len(patches[s].centroid):
                    continue
                dist, kk = cKDTree(patches[s].centroid[:, :2]).query(control_local[:, :2],
                                                                    distance_upper_bound=p.cell / 2)  # fmt: skip
                ok = np.isfinite(dist)
                if not ok.any():
                    continue
                sa, ga = patch_points(patches[s], kk[ok])
                parts["surf"].append(sa)
                parts["sg"].append(ga + k)
                parts["fixed"].append(control_local[ok])
                parts["fg"].append(np.arange(int(ok.sum())) + k)
                parts["origin"].append(patches[s].origin[kk[ok]])
                parts["strips"].append(np.tile([s, 0], (int(ok.sum()), 1)))
                parts["weight"].append(np.full(int(ok.sum()), 100.0))  # a surveyed point weighs as 100 points
                parts["rms"].append(np.full(int(ok.sum()), np.inf))
                k += int(ok.sum())
        if k == 0:
            return None

        def cat(name, empty):
            return np.concatenate(parts[name]) if parts[name] else empty

        links = Links(cat("surf", np.zeros(0, np.int64)), cat("sg", np.zeros(0, np.int64)),
                      cat("obs", np.zeros(0, np.int64)), cat("og", np.zeros(0, np.int64)), cat("origin", None),
                      cat("strips", None), cat("weight", None), cat("fixed", np.zeros((0, 3))),
                      cat("fg", np.zeros(0, np.int64)))  # fmt: skip
        rms = cat("rms", None)
        # the observed points must fit the surface as well as each strip fits its own (else the surface
        # is not the same there: edges, kinks, canopy); as for the rigid model
        d, g = distances(links, xyz)
        cnt = np.maximum(np.bincount(g, minlength=k), 1)
        mean = np.bincount(g, d, k) / cnt
        spread = np.sqrt(np.clip(np.bincount(g, d * d, k) / cnt - mean**2, 0, None))
        keep = (spread <= 2.0 * rms + 0.005) & (np.abs(mean) <= p.max_distance)
        links = _select(links, keep)
        if links.size == 0:
            return None
        used = np.unique(np.concatenate((links.surf, links.obs)))
        links.surf = np.searchsorted(used, links.surf)
        links.obs = np.searchsorted(used, links.obs)
        return links, used

    return find


def _select(links: Links, keep: np.ndarray) -> Links:
    new = np.cumsum(keep) - 1
    ms, mo, mf = keep[links.surf_group], keep[links.obs_group], keep[links.fixed_group]
    return Links(links.surf[ms], new[links.surf_group[ms]], links.obs[mo], new[links.obs_group[mo]],
                 links.origin[keep], links.strips[keep], links.weight[keep], links.fixed[mf],
                 new[links.fixed_group[mf]])  # fmt: skip


def check_model(params, config) -> None:
    """``model: mounting`` needs the pulses and the trajectory: a raw flight."""
    if params.model == "mounting" and config.input.format == "las":
        raise ConfigError(
            "stages.strip_adjust.model: mounting needs a raw flight's pulses and trajectory, and input.format "
            "las has none; use model: rigid (the default) for LAS input."
        )


def run(ctx, write_rasters) -> None:
    """The stage's work under ``model: mounting`` (see the module notes)."""
    import json

    from dtm.common.clouds import cloud_info
    from dtm.common.columns import read_columns

    p = ctx.params
    mp = p.mounting
    src = ctx.inputs["points_georef"]
    traj, tmeta = read_columns(ctx.inputs["trajectory"])
    pulses, pmeta = read_columns(ctx.inputs["pulses"])
    geo = _Geometry(ctx, traj, tmeta, pulses, pmeta)
    info = cloud_info(src)
    t_las, sid, is_single = _read_points(src)
    idx = pulse_index(pulses["time"], t_las)
    del t_las
    from dtm.common.georeferencing import locate
    from dtm.stages.strip_adjust.mounting import georeference_sample

    # the estimation sample: single returns of strips, on a lattice of cells above max_points
    single = np.flatnonzero(is_single & (sid > 0))
    ids = idx[single]
    i_s, f_s, _ = locate(geo.exact, np.asarray(pulses["time"], dtype=np.float64)[ids], float("inf"))
    v_s = np.column_stack([np.asarray(pulses[k], dtype=np.float64)[ids] for k in ("x", "y", "z")])
    base = Sample(i_s, f_s, v_s, sid[single].astype(np.int64))
    unknowns0 = make_unknowns(lever_arm=False, range_offset=False, offset_strips=[], reference=None,
                              limits=(1.0, 1.0, 1.0, 1.0))  # fmt: skip
    local = georeference_sample(geo.exact, geo.mounting, base, np.zeros(unknowns0.size), unknowns0)
    step = max(1, int(np.ceil(np.sqrt(len(single) / p.max_points))))
    if step > 1:
        ix, iy = np.floor(local[:, 0] / p.cell).astype(np.int64), np.floor(local[:, 1] / p.cell).astype(np.int64)
        lattice = np.flatnonzero((ix % step == 0) & (iy % step == 0))
        base = base.subset(lattice)
        ctx.log.info("estimation on every %d-th cell in x and y: %d single returns", step, len(lattice))
    del i_s, f_s, v_s, ids
    counts = np.bincount(base.strip, minlength=1)
    strips = [int(s) for s in np.flatnonzero(counts) if s > 0 and counts[s] >= p.min_points]
    control = None
    if p.control_points is not None:
        from dtm.common.checkpoints import read_control

        control = geo.map_to_local(read_control(p.control_points))
        if geo.output is not geo.exact:  # ltp output: control in the ltp plane; estimate in it too
            control = None
            ctx.log.warning("control points are not used by model: mounting with frame: ltp")
    reference = p.reference_strip if p.reference_strip != "most_overlap" else None
    if mp.strip_offsets and reference is None and strips:
        reference = max(strips, key=lambda s: counts[s])  # the datum of the offsets: the best-sampled strip
    unknowns = make_unknowns(lever_arm=mp.lever_arm, range_offset=mp.range_offset,
                             offset_strips=strips if mp.strip_offsets else [],
                             reference=None if control is not None else reference,
                             limits=(mp.max_sigma_boresight_deg, mp.max_sigma_lever_arm_m, mp.max_sigma_range_offset_m,
                                     p.max_sigma_translation_m))  # fmt: skip

    def progress(rnd, theta, sigma, n):
        ctx.log.info("round %d: %d correspondences, residual sigma %.4f m, boresight correction %s deg", rnd + 1,
                     n, sigma, np.round(np.degrees(theta[:3]), 5).tolist())  # fmt: skip

    cal = None
    if len(strips) >= 2:
        cal = solve(geo.exact, geo.mounting, base, _link_finder(base, strips, p, control), unknowns,
                    rounds=mp.rounds, max_iterations=p.max_iterations, max_correlation=mp.max_correlation,
                    min_significance=mp.min_significance, log=progress)  # fmt: skip
    note = None
    if cal is None:
        note = f"{len(strips)} strip(s) without planar overlap: nothing to estimate, points passed on unchanged"
        theta = np.zeros(unknowns.size)
    else:
        theta = cal.theta
    if not unknowns.offset_strips:
        datum = "the trajectory (no strip offsets)"
    elif control is not None:
        datum = "control points"
    else:
        datum = f"strip {reference} (its offsets held)"
    summary, pair_rows, before, after = _summary(cal, unknowns, theta, geo, note, pmeta, p.cell, datum)
    summary["strips"] = _strip_rows(summary, unknowns, strips, np.bincount(sid, minlength=max(strips, default=0) + 1))
    if not pair_rows:
        from pipeline.runner import UNPUBLISHED

        ctx.metrics[UNPUBLISHED] = ["strip_difference_before", "strip_difference_after", "strip_difference_png"]
    moved = _write(ctx, src, ctx.outputs["points_adjusted"], geo, theta, unknowns, idx, pulses, info.units)
    summary["largest_point_move_m"] = round(moved, 5)
    ctx.outputs["strip_corrections"].write_text(json.dumps(summary, indent=2) + "\n")
    write_rasters(ctx, info.extent, before, after, p.difference_resolution, info.crs, info.units)
    rms_b = _combined([r["rms_before_m"] for r in pair_rows], [r["points"] for r in pair_rows])
    rms_a = _combined([r["rms_after_m"] for r in pair_rows], [r["points"] for r in pair_rows])
    held = [u["name"] for u in summary["unknowns"] if u["held_because"]]
    by = {u["name"]: u for u in summary["unknowns"]}
    ctx.metrics.update(
        model="mounting", note=note, strips=len(strips), pairs=len(pair_rows), datum=summary["datum"],
        boresight_correction_deg=[by[n]["correction"] for n in ("boresight_roll", "boresight_pitch", "boresight_yaw")],
        boresight_estimate_deg=[by[n]["estimate"] for n in ("boresight_roll", "boresight_pitch", "boresight_yaw")],
        not_significant=[u["name"] for u in summary["unknowns"] if u["not_applied_because"]],
        boresight_sigma_deg=[by[n]["sigma"] for n in ("boresight_roll", "boresight_pitch", "boresight_yaw")],
        lever_arm_correction_m=[by[n]["correction"] for n in ("lever_arm_x", "lever_arm_y", "lever_arm_z")],
        lever_arm_sigma_m=[by[n]["sigma"] for n in ("lever_arm_x", "lever_arm_y", "lever_arm_z")],
        range_offset_m=by["range_offset"]["correction"], range_offset_sigma_m=by["range_offset"]["sigma"],
        not_determined=held, overlap_rms_before_m=rms_b, overlap_rms_after_m=rms_a,
        overlap_systematic_rms_before_m=_combined([r["systematic_rms_before_m"] for r in pair_rows],
                                                  [r["patches"] for r in pair_rows]),
        overlap_systematic_rms_after_m=_combined([r["systematic_rms_after_m"] for r in pair_rows],
                                                 [r["patches"] for r in pair_rows]),
        largest_point_move_m=moved, residual_sigma_m=cal.residual_sigma if cal else None,
        iterations=cal.iterations if cal else 0, correspondences=cal.links.size if cal else 0,
        estimation_points=len(base.strip), lattice_step=step,
    )  # fmt: skip
    for u in summary["unknowns"]:
        if u["held_because"]:
            ctx.log.warning("%s cannot be determined by this flight (%s): held at the configured value; "
                            "it would be determined by %s", u["name"], u["held_because"], u["determined_by"])  # fmt: skip
    if note:
        ctx.log.info("mounting calibration skipped: %s", note)
    else:
        est = ", ".join(f"{u['name']} {u['estimate']:+.5f} +- {u['sigma']:.5f} {u['unit']}"
                        + ("" if u["applied"] else " (not significant: not applied)")
                        for u in summary["unknowns"] if u["estimated"] and not u["name"].startswith("strip_"))  # fmt: skip
        ctx.log.info("mounting estimates: %s", est or "none (every unknown held)")
        ctx.log.info("%d strips, %d pairs: overlap RMS %.4f m -> %.4f m; largest point move %.4f m", len(strips),
                     len(pair_rows), rms_b or 0.0, rms_a or 0.0, moved)  # fmt: skip
        if held:
            ctx.metrics["warnings"] = [f"{n} not determined: held at the configured value" for n in held]


def _combined(values, weights):
    if not values:
        return None
    v, w = np.asarray(values, dtype=np.float64), np.asarray(weights, dtype=np.float64)
    return float(np.sqrt(np.sum(w * v**2) / np.sum(w)))


def _strip_rows(summary: dict, unknowns, strips: list[int], counts: np.ndarray) -> dict:
    """Per strip, in the rigid model's layout (the report reads it): the strip's trajectory offset as its
    translation (zero unless ``strip_offsets``), no rotation (the mounting turns it, see ``unknowns``)."""
    by = {u["name"]: u for u in summary["unknowns"]}
    rows = {}
    for s in strips:
        names = [f"strip_{s}_offset_{a}" for a in "enu"]
        t = [by[n]["correction"] if n in by else 0.0 for n in names]
        sd = [(by[n]["sigma"] or 0.0) if n in by else 0.0 for n in names]
        rows[str(s)] = {"translation_m": t, "rotation_deg": [0.0, 0.0, 0.0], "sigma_translation_m": sd,
                        "sigma_rotation_deg": [0.0, 0.0, 0.0], "points": int(counts[s])}  # fmt: skip
    return rows


def _summary(cal, unknowns, theta, geo, note, pmeta, cell, datum):
    """strip_corrections.json for the mounting model, the per-pair rows, and the difference-map values."""
    from scipy.spatial.transform import Rotation

    from dtm.stages.strip_adjust.mounting import georeference_sample

    rows = []
    for j, name in enumerate(unknowns.names):
        angle = j < 3
        scale, digits = (180 / np.pi, 7) if angle else (1.0, 5)
        estimated = cal is not None and j in cal.free
        why = cal.held.get(j) if cal is not None else None
        key = "strip_offset" if name.startswith("strip_") else name
        rows.append({
            "name": name, "unit": "deg" if angle else "m",
            "correction": round(float(theta[j] * scale), digits),
            "estimate": round(float(cal.estimate[j] * scale), digits) if estimated else None,
            "sigma": round(float(cal.sigma[j] * scale), digits) if estimated else None,
            "estimated": bool(estimated), "applied": bool(estimated and j not in cal.not_significant),
            "not_applied_because": cal.not_significant.get(j) if estimated else None,
            "held_because": why, "determined_by": ADVICE[key] if why else None,
        })  # fmt: skip
    new = corrected_mounting(geo.mounting, theta)
    summary = {
        "model": "mounting",
        "datum": None if note else datum,
        "note": note,
        "unknowns": rows,
        "correlation": {"names": [unknowns.names[j] for j in cal.free] if cal else [],
                        "matrix": np.round(cal.correlation, 4).tolist() if cal else []},
        "mounting": {
            "configured_rotation": np.round(geo.mounting.rotation, 9).tolist(),
            "configured_lever_arm_m": np.round(geo.mounting.lever_arm, 5).tolist(),
            "estimated_rotation": np.round(new.rotation, 9).tolist(),
            "estimated_lever_arm_m": np.round(new.lever_arm, 5).tolist(),
            "range_offset_m": round(float(theta[6]), 5),
        },
        "residual_sigma_m": round(float(cal.residual_sigma), 5) if cal else None,
        "iterations": cal.iterations if cal else 0,
        "pairs": [],
    }  # fmt: skip
    if "boresight_deg" in pmeta:  # lmsq: the value to configure as input.boresight_deg
        yaw, pitch, roll = Rotation.from_matrix(new.rotation).as_euler("ZYX", degrees=True)
        summary["mounting"]["estimated_boresight_deg"] = [round(float(v), 6) for v in (roll, pitch, yaw)]
    if cal is None:
        return summary, [], None, None
    links, sample = cal.links, cal.sample
    d0, g = distances(links, georeference_sample(geo.exact, geo.mounting, sample, np.zeros_like(theta), unknowns))
    d1, _ = distances(links, georeference_sample(geo.exact, geo.mounting, sample, theta, unknowns))
    k = links.size
    cnt = np.maximum(np.bincount(g, minlength=k), 1)
    m0, m1 = np.bincount(g, d0, k) / cnt, np.bincount(g, d1, k) / cnt
    centres = np.column_stack(geo.to_map(*links.origin.T))
    before, after = [], []
    for a, b in sorted({tuple(r) for r in links.strips.tolist() if r[1] > 0}):
        lk = (links.strips[:, 0] == a) & (links.strips[:, 1] == b)
        pts = lk[g]
        summary["pairs"].append({
            "strips": [a, b], "overlap_area_m2": round(float(lk.sum() * cell * cell), 1), "patches": int(lk.sum()),
            "points": int(pts.sum()),
            "rms_before_m": round(float(np.sqrt(np.mean(d0[pts] ** 2))), 4),
            "rms_after_m": round(float(np.sqrt(np.mean(d1[pts] ** 2))), 4),
            "systematic_rms_before_m": round(float(np.sqrt(np.mean(m0[lk] ** 2))), 4),
            "systematic_rms_after_m": round(float(np.sqrt(np.mean(m1[lk] ** 2))), 4),
        })  # fmt: skip
        before.append((centres[lk], m0[lk]))
        after.append((centres[lk], m1[lk]))
    return summary, summary["pairs"], before, after


def _write(ctx, src, dst, geo, theta, unknowns, idx, pulses, units) -> float:
    """Copy *src* to *dst* with every point georeferenced again under *theta*; the largest move (m)."""
    import laspy

    from dtm.common.clouds import open_las_writer
    from dtm.common.georeferencing import georeference_local, locate

    new = corrected_mounting(geo.mounting, theta)
    table = np.zeros((65536, 3))
    for k, s in enumerate(unknowns.offset_strips):
        table[s] = theta[7 + 3 * k : 10 + 3 * k]
    pulses_t = pulses["time"]
    pulses_v = [pulses[k] for k in ("x", "y", "z")]
    largest = 0.0
    start = 0
    with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
        with ctx.progress(reader.header.point_count, "writing", unit="pt") as bar:
            for chunk in reader.chunk_iterator(1_000_000):
                n = len(chunk)
                if n:
                    ids = idx[start : start + n]
                    t = np.asarray(pulses_t[ids], dtype=np.float64)
                    v = np.column_stack([np.asarray(c[ids], dtype=np.float64) for c in pulses_v])
                    v *= (1.0 + theta[6] / np.maximum(np.linalg.norm(v, axis=1), 1e-9))[:, None]
                    i, f, _ = locate(geo.output, t, float("inf"))
                    e, nn, u = georeference_local(geo.output, v[:, 0], v[:, 1], v[:, 2], new, i, f)
                    off = table[np.asarray(chunk.point_source_id).astype(np.int64)]
                    x, y, z = geo.to_map(e + off[:, 0], nn + off[:, 1], u + off[:, 2])
                    old = np.column_stack((np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)))
                    moved = units.to_metres(np.column_stack((x, y, z))) - units.to_metres(old)
                    largest = max(largest, float(np.max(np.linalg.norm(moved, axis=1))))
                    chunk.x, chunk.y, chunk.z = x, y, z
                writer.write_points(chunk)
                bar.update(n)
                start += n
    return largest
