#!/usr/bin/env python3
"""Reference run of xdem's Nuth & Kaab coregistration, for benchmarking a Rust port.

Usage:
    python3 xdem_nk.py REF.tif TBA.tif [--nodata V] [--stable-mask MASK.tif]
                       [--geographic {utm,pixel,error}] [--subsample N] [--max-iterations N]

Prints ONE JSON object on stdout. Never writes any file (GDAL PAM disabled so no .aux.xml).

Conventions
-----------
* DoD = TBA - REF (on the REF grid; TBA resampled bilinearly onto it if grids differ).
* shift_* are exactly what xdem stores in nk.meta["outputs"]["affine"] (== nk.to_translations()):
  the translation that xdem APPLIES to the TBA DEM (TBA georeference moved by +shift_x east,
  +shift_y north, elevations + shift_z) to align it on REF.
* shift_*_px = shift_*_m / pixel size of the grid the fit ran on (x: transform.a, y: |transform.e|),
  so +shift_y_px means "north", i.e. towards row index decreasing.
* Geographic CRS: xdem's NuthKaab refuses it (NotImplementedError, message reported in
  "xdem_geographic_error"). --geographic selects the workaround:
    utm   (default) reproject REF (bilinear, rasterio default resolution) to the local UTM
          CRS (ref.get_metric_crs()), and TBA onto that grid (bilinear).
    pixel relabel the native grid as a projected CRS with 1x1 square pixels (no resampling):
          shifts come out directly in native pixels. Because xdem computes slope/aspect with
          np.gradient in pixel units, this equals a pure pixel-grid Nuth & Kaab.
    error just report the error.
"""
from __future__ import annotations

import os

os.environ.setdefault("GDAL_PAM_ENABLED", "NO")  # never write .aux.xml next to inputs

import argparse
import json
import logging
import sys
import time
import warnings

import numpy as np
import rasterio
from affine import Affine
from rasterio.crs import CRS

import xdem
import xdem.coreg.affine as xaff
from geoutils.stats import nmad as gu_nmad


def _js(o):
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


def log(*a):
    print(*a, file=sys.stderr)


def load_dem(path: str, extra_nodata: float | None) -> xdem.DEM:
    with rasterio.open(path) as ds:
        arr = ds.read(1).astype(np.float32)
        declared = ds.nodata
        transform = ds.transform
        crs = ds.crs
        aop = ds.tags().get("AREA_OR_POINT")
    mask = ~np.isfinite(arr)
    if declared is not None:
        mask |= arr == np.float32(declared)
    if extra_nodata is not None:
        mask |= arr == np.float32(extra_nodata)
    arr[mask] = np.nan
    nd = -9999.0
    if np.any(arr == nd):
        nd = float(np.finfo(np.float32).min)
    aop = aop if aop in ("Area", "Point") else None
    ma = np.ma.masked_array(arr, mask=mask)
    return xdem.DEM.from_array(ma, transform=transform, crs=crs, nodata=nd, area_or_point=aop)


def valid_array(dem) -> np.ndarray:
    return np.ma.filled(dem.data.astype(np.float64), np.nan).squeeze()


def stats(d: np.ndarray) -> dict:
    d = d[np.isfinite(d)]
    if d.size == 0:
        return {"count": 0}
    med = float(np.median(d))
    return {
        "count": int(d.size),
        "mean": float(np.mean(d)),
        "median": med,
        "std": float(np.std(d)),
        "rmse": float(np.sqrt(np.mean(d * d))),
        "nmad": float(1.4826 * np.median(np.abs(d - med))),
        "nmad_geoutils": float(gu_nmad(d)),
        "min": float(np.min(d)),
        "max": float(np.max(d)),
    }


def same_grid(a, b) -> bool:
    return a.crs == b.crs and a.shape == b.shape and a.transform.almost_equals(b.transform)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("ref")
    ap.add_argument("tba")
    ap.add_argument("--nodata", type=float, default=None, help="extra nodata value for both DEMs")
    ap.add_argument("--stable-mask", default=None, help="raster; non-zero & valid = stable/inlier")
    ap.add_argument("--geographic", choices=["utm", "pixel", "error"], default="utm")
    ap.add_argument("--subsample", type=float, default=1, help="xdem subsample (1 = all valid pixels)")
    ap.add_argument("--max-iterations", type=int, default=10, help="xdem default 10")
    args = ap.parse_args()

    warnings.simplefilter("ignore")
    out: dict = {"xdem_version": xdem.__version__, "ref": args.ref, "tba": args.tba, "extra_nodata": args.nodata}

    ref = load_dem(args.ref, args.nodata)
    tba = load_dem(args.tba, args.nodata)
    out["ref_crs"] = ref.crs.to_string()
    out["ref_shape"] = list(ref.shape)
    out["ref_res"] = [float(ref.transform.a), float(abs(ref.transform.e))]
    out["tba_on_ref_grid_originally"] = same_grid(ref, tba)
    if not same_grid(ref, tba):
        tba = tba.reproject(ref, resampling="bilinear", silent=True)

    stable = None
    if args.stable_mask:
        m = load_dem(args.stable_mask, None)
        if not same_grid(ref, m):
            m = m.reproject(ref, resampling="nearest", silent=True)
        mv = valid_array(m)
        stable = np.isfinite(mv) & (mv != 0)
        out["stable_mask_pixels"] = int(stable.sum())

    # ---- geographic CRS handling -------------------------------------------------------
    fit_ref, fit_tba, fit_stable = ref, tba, stable
    out["fit_grid"] = "native"
    if not ref.crs.is_projected:
        try:
            xdem.coreg.NuthKaab(subsample=args.subsample, max_iterations=args.max_iterations).fit(ref, tba, inlier_mask=stable)
            out["xdem_geographic_error"] = None
        except Exception as e:  # noqa: BLE001
            out["xdem_geographic_error"] = f"{type(e).__name__}: {e}"
            log("xdem on geographic CRS:", out["xdem_geographic_error"])
        if args.geographic == "error":
            print(json.dumps(out, indent=1, default=_js))
            return 1
        if args.geographic == "utm":
            utm = ref.get_metric_crs()
            fit_ref = ref.reproject(crs=utm, resampling="bilinear", silent=True)
            fit_tba = tba.reproject(fit_ref, resampling="bilinear", silent=True)
            if stable is not None:
                sm = xdem.DEM.from_array(stable.astype(np.float32), ref.transform, ref.crs, nodata=-1)
                fit_stable = valid_array(sm.reproject(fit_ref, resampling="nearest", silent=True)) > 0.5
            out["fit_grid"] = f"reprojected to {utm.to_string()} (bilinear)"
        else:  # pixel
            fake_crs = CRS.from_epsg(32631)  # any projected CRS; only is_projected matters to xdem
            pix_tr = Affine(1.0, 0.0, 0.0, 0.0, -1.0, float(ref.shape[0]))
            fit_ref = xdem.DEM.from_array(ref.data, pix_tr, fake_crs, nodata=ref.nodata, area_or_point=ref.area_or_point)
            fit_tba = xdem.DEM.from_array(tba.data, pix_tr, fake_crs, nodata=tba.nodata, area_or_point=ref.area_or_point)
            out["fit_grid"] = "native grid relabelled as projected, 1x1 px (shift units = native pixels)"
        out["fit_grid_shape"] = list(fit_ref.shape)
        out["fit_grid_res"] = [float(fit_ref.transform.a), float(abs(fit_ref.transform.e))]

    # ---- stats before ------------------------------------------------------------------
    r = valid_array(fit_ref)
    dod_before = valid_array(fit_tba) - r
    sel = np.ones_like(r, dtype=bool) if fit_stable is None else fit_stable
    out["stats_before"] = stats(dod_before[sel])
    if fit_stable is not None:
        out["stats_before_all_pixels"] = stats(dod_before)

    # ---- instrument iterations (wraps the module-level step function; no behaviour change) --
    iters: list = []
    orig_step = xaff._nuth_kaab_iteration_step

    def counting_step(coords_offsets, *a, **k):
        res = orig_step(coords_offsets, *a, **k)
        iters.append({"offsets_m": [float(v) for v in res[0]], "step_px": float(res[1])})
        return res

    xaff._nuth_kaab_iteration_step = counting_step

    # ---- fit ---------------------------------------------------------------------------
    nk = xdem.coreg.NuthKaab(subsample=args.subsample, max_iterations=args.max_iterations)  # rest default
    t0 = time.perf_counter()
    nk.fit(fit_ref, fit_tba, inlier_mask=fit_stable)
    out["fit_seconds"] = time.perf_counter() - t0
    xaff._nuth_kaab_iteration_step = orig_step

    aff = nk.meta["outputs"]["affine"]
    sx, sy, sz = (float(aff["shift_x"]), float(aff["shift_y"]), float(aff["shift_z"]))
    resx, resy = float(fit_ref.transform.a), float(abs(fit_ref.transform.e))
    out.update(
        shift_x_m=sx, shift_y_m=sy, shift_z_m=sz,
        shift_x_px=sx / resx, shift_y_px=sy / resy,
        to_translations=[float(v) for v in nk.to_translations()],
        iterations=len(iters),
        iteration_trace=iters,
        subsample_final=nk.meta["outputs"].get("random", {}).get("subsample_final"),
        nk_inputs={k: (v if isinstance(v, (int, float, str, bool)) or v is None else getattr(v, "__name__", str(v)))
                   for lv in nk.meta["inputs"].values() for k, v in lv.items()},
    )
    if out["fit_grid"] != "native":
        # Express the shift also in native REF pixels (approximate for the utm case).
        if out["fit_grid"].startswith("reprojected"):
            lat = np.deg2rad(ref.bounds.bottom / 2 + ref.bounds.top / 2)
            mx = float(ref.transform.a) * 111319.49079327357 * np.cos(lat)
            my = float(abs(ref.transform.e)) * 110946.0  # ~metres per degree latitude near mid-latitudes
            out["shift_native_px_approx"] = [sx / mx, sy / my]
        else:
            out["shift_native_px_approx"] = [sx, sy]

    # ---- apply and stats after ---------------------------------------------------------
    t0 = time.perf_counter()
    aligned = nk.apply(fit_tba)  # default: resample=True, resampling="bilinear" onto the input grid
    out["apply_seconds"] = time.perf_counter() - t0
    dod_after = valid_array(aligned) - r
    out["stats_after"] = stats(dod_after[sel])
    if fit_stable is not None:
        out["stats_after_all_pixels"] = stats(dod_after)
    out["nmad_before"] = out["stats_before"].get("nmad")
    out["nmad_after"] = out["stats_after"].get("nmad")

    print(json.dumps(out, indent=1, default=_js))
    return 0


if __name__ == "__main__":
    logging.getLogger().setLevel(logging.WARNING)
    sys.exit(main())
