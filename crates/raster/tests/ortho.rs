//! Orthomosaics of scenes rendered here by ray casting through a distorted camera model: a flat
//! textured ground seen by four nadir views (one over-exposed), and a box that hides ground from
//! an oblique view.

use std::sync::Arc;

use nalgebra::{Matrix3, Vector2, Vector3};
use timesift_core::{BrownCamera, Camera, CameraModel, Pose};
use timesift_raster::{
    Lattice, OrthoMosaic, OrthoOptions, OrthoView, RasterError, RgbImage, ViewImages, ortho_stats,
    orthomosaic, orthomosaic_by_rows,
};

/// Ground colour: smooth enough for bilinear sampling, varied enough to show seams.
fn texture(x: f64, y: f64) -> [f64; 3] {
    [
        110.0 + 50.0 * (0.9 * x).sin() * (0.7 * y).cos(),
        100.0 + 40.0 * (0.5 * x + 0.8 * y).sin(),
        90.0 + 30.0 * (0.3 * x * y).cos(),
    ]
}

struct Images(Vec<Arc<RgbImage>>);

impl ViewImages for Images {
    fn image(&self, view: usize) -> Result<Arc<RgbImage>, String> {
        self.0
            .get(view)
            .cloned()
            .ok_or_else(|| format!("no view {view}"))
    }
}

fn camera() -> Camera {
    let mut c = BrownCamera::new(360, 300, 330.0).unwrap();
    c.k1 = -0.04;
    c.k2 = 0.01;
    Camera::Brown(c)
}

fn nadir(x: f64, y: f64, z: f64) -> Pose {
    let r = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
    let c = Vector3::new(x, y, z);
    Pose::from_rt(&r, &(-(r * c))).unwrap()
}

/// Renders a heightfield (`height`, walked in small steps) through a view, colours × `gain`.
fn render(
    view: &OrthoView,
    height: &dyn Fn(f64, f64) -> f64,
    colour: &dyn Fn(f64, f64, f64) -> [f64; 3],
    gain: f64,
) -> RgbImage {
    let cam = &view.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let world_from_cam = view.cam_from_world.inverse();
    let c = view.cam_from_world.center();
    let mut data = vec![0u8; 3 * w * h];
    for v in 0..h {
        for u in 0..w {
            let Ok(ray) = cam.unproject(&Vector2::new(u as f64 + 0.5, v as f64 + 0.5)) else {
                continue;
            };
            let d = (world_from_cam.rotation * ray).normalize();
            // March until below the surface, then bisect.
            let (mut lo, mut hi) = (0.0, 0.0);
            let mut s = 0.0;
            while s < 200.0 {
                let p = c + d * s;
                if p.z <= height(p.x, p.y) {
                    hi = s;
                    break;
                }
                lo = s;
                s += 0.02;
            }
            if hi == 0.0 {
                continue;
            }
            for _ in 0..40 {
                let m = 0.5 * (lo + hi);
                let p = c + d * m;
                if p.z <= height(p.x, p.y) {
                    hi = m;
                } else {
                    lo = m;
                }
            }
            let p = c + d * hi;
            let rgb = colour(p.x, p.y, p.z);
            for b in 0..3 {
                data[3 * (v * w + u) + b] = (rgb[b] * gain).round().clamp(1.0, 255.0) as u8;
            }
        }
    }
    RgbImage {
        width: w,
        height: h,
        data,
    }
}

#[test]
fn flat_ground_is_reproduced_and_an_overexposed_view_is_compensated() {
    let lattice = Lattice::new(0.0, 20.0, 0.25, 80, 80).unwrap();
    let heights = vec![0.0f32; lattice.len()];
    let views: Vec<OrthoView> = [(6.0, 6.0), (14.0, 6.0), (6.0, 14.0), (14.0, 14.0)]
        .iter()
        .map(|&(x, y)| OrthoView {
            camera: camera(),
            cam_from_world: nadir(x, y, 25.0),
        })
        .collect();
    let gains = [1.0, 1.0, 1.0, 1.3];
    let images = Images(
        views
            .iter()
            .zip(gains)
            .map(|(v, g)| Arc::new(render(v, &|_, _| 0.0, &|x, y, _| texture(x, y), g)))
            .collect(),
    );
    let options = OrthoOptions {
        factor: 2,
        tile: 24,
        ..OrthoOptions::default()
    };
    let ortho = orthomosaic(&heights, &lattice, &views, &images, &options, &|_, _| {}).unwrap();
    let ol = ortho.lattice;
    assert_eq!((ol.width(), ol.height()), (160, 160));
    assert_eq!(ortho.stats.painted_cells, ol.len(), "every cell is seen");
    // Colours against the texture: the fitted gains bring view 4 to the others' level. The
    // mosaic's overall level is the gauge of the fit (the mean gain is pulled to 1), so the
    // texture is compared at the level of view 1, whose true gain is 1.
    let level = ortho.gains[0];
    let mut err = 0.0;
    for r in 0..ol.height() {
        for c in 0..ol.width() {
            let (x, y) = ol.cell_center(c, r);
            let t = texture(x, y);
            let i = 4 * (r * ol.width() + c);
            for b in 0..3 {
                err += (ortho.rgba[i + b] as f64 - level[b] * t[b]).abs();
            }
        }
    }
    let mean_err = err / (3 * ol.len()) as f64;
    assert!(mean_err < 2.5, "mean colour error {mean_err}");
    for b in 0..3 {
        let ratio = ortho.gains[3][b] / ortho.gains[0][b];
        assert!((ratio - 1.0 / 1.3).abs() < 0.02, "gain ratio {ratio}");
    }
    let s = ortho.stats;
    assert!(s.seam_cells > 0);
    assert!(
        s.seam_jump < 1.5 * s.interior_jump + 1.0,
        "seams {:.2} vs interior {:.2}",
        s.seam_jump,
        s.interior_jump
    );

    // Without compensation the over-exposed view shows as a step at its seams.
    let raw = orthomosaic(
        &heights,
        &lattice,
        &views,
        &images,
        &OrthoOptions {
            gain_compensation: false,
            feather: 0,
            ..options
        },
        &|_, _| {},
    )
    .unwrap();
    assert!(
        raw.stats.seam_jump > 2.0 * s.seam_jump,
        "{} vs {}",
        raw.stats.seam_jump,
        s.seam_jump
    );

    // The same mosaic whatever the number of threads.
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| {
            orthomosaic(&heights, &lattice, &views, &images, &options, &|_, _| {}).unwrap()
        });
    assert_eq!(single, ortho);

    // Band by band (what a mosaic larger than memory is written from): whole rows, in order,
    // each band at most a tile of DEM cells tall, together the same mosaic; a band the caller
    // cannot take stops the work with its reason.
    let by_rows = |rows: &mut timesift_raster::RowSink<'_>| {
        orthomosaic_by_rows(
            &heights,
            &lattice,
            &views,
            &images,
            &options,
            &|_, _| {},
            rows,
        )
    };
    let mut bands = Vec::new();
    let mut next_row = 0;
    let summary = by_rows(&mut |first_row, rgba| {
        assert_eq!(first_row, next_row);
        assert_eq!(rgba.len() % (4 * ol.width()), 0);
        next_row += rgba.len() / (4 * ol.width());
        bands.push(rgba.to_vec());
        Ok(())
    })
    .unwrap();
    assert_eq!(next_row, ol.height());
    assert_eq!(
        bands.len(),
        160usize.div_ceil(options.tile * options.factor)
    );
    assert_eq!(bands.concat(), ortho.rgba);
    assert_eq!((&summary.gains, summary.stats), (&ortho.gains, ortho.stats));
    let mut taken = 0;
    let full_disk = by_rows(&mut |_, _| {
        taken += 1;
        if taken == 2 {
            Err("disk full".into())
        } else {
            Ok(())
        }
    });
    assert_eq!(full_disk, Err(RasterError::Output("disk full".into())));
    assert_eq!(taken, 2);

    // In parts, as a cluster makes it: the gains once, then disjoint ranges of tile rows in any
    // order (here the last first, each with its own thread pool), their rows put in place and
    // their figures summed top to bottom: the same mosaic and figures, bit for bit.
    let mosaic = OrthoMosaic::new(&heights, &lattice, &views, &options).unwrap();
    assert_eq!(mosaic.lattice(), &ol);
    let gains = mosaic.gains(&images, &|_, _| {}).unwrap();
    assert_eq!(gains, ortho.gains);
    let tile_rows = mosaic.tile_rows();
    assert_eq!(tile_rows, 80usize.div_ceil(options.tile));
    let parts = [0..1, 1..3, 3..tile_rows];
    let mut rgba = vec![0u8; ortho.rgba.len()];
    let mut figures = vec![Vec::new(); parts.len()];
    for (k, part) in parts.iter().enumerate().rev() {
        let rows = mosaic.ortho_rows(part.clone());
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(k + 1)
            .build()
            .unwrap();
        figures[k] = pool
            .install(|| {
                mosaic.make_rows(
                    part.clone(),
                    &images,
                    &gains,
                    &|_, _| {},
                    &mut |first, band| {
                        assert!(rows.contains(&first));
                        let at = 4 * first * ol.width();
                        rgba[at..at + band.len()].copy_from_slice(band);
                        Ok(())
                    },
                )
            })
            .unwrap();
        assert_eq!(figures[k].len(), part.len());
    }
    assert_eq!(rgba, ortho.rgba);
    assert_eq!(ortho_stats(&figures.concat()), ortho.stats);
    // Gains that do not match the views are refused, not indexed out of bounds.
    assert!(matches!(
        mosaic.make_rows(0..1, &images, &gains[..2], &|_, _| {}, &mut |_, _| Ok(())),
        Err(RasterError::InvalidInput(_))
    ));
}

#[test]
fn ground_hidden_by_a_box_is_not_painted_from_the_view_that_cannot_see_it() {
    let lattice = Lattice::new(0.0, 20.0, 0.25, 80, 80).unwrap();
    // A 4 m high box over x, y ∈ [8, 12].
    let inside = |x: f64, y: f64| (8.0..12.0).contains(&x) && (8.0..12.0).contains(&y);
    let height = |x: f64, y: f64| if inside(x, y) { 4.0 } else { 0.0 };
    let heights: Vec<f32> = (0..lattice.len())
        .map(|i| {
            let (x, y) = lattice.cell_center(i % 80, i / 80);
            height(x, y) as f32
        })
        .collect();
    // The roof is red, the ground grey-green; the only view is oblique from the west, so the
    // ground just east of the box is hidden from it.
    let colour = |x: f64, y: f64, z: f64| {
        if z > 2.0 {
            [230.0, 20.0, 20.0]
        } else {
            let t = texture(x, y);
            [t[1] * 0.5, t[1], t[1] * 0.8]
        }
    };
    let centre = Vector3::new(-8.0, 10.0, 18.0);
    let view = OrthoView {
        camera: camera(),
        cam_from_world: Pose::look_at(&centre, &Vector3::new(10.0, 10.0, 0.0)).unwrap(),
    };
    let images = Images(vec![Arc::new(render(&view, &height, &colour, 1.0))]);
    let options = OrthoOptions {
        factor: 1,
        tile: 32,
        gain_compensation: false,
        ..OrthoOptions::default()
    };
    let ortho = orthomosaic(&heights, &lattice, &[view], &images, &options, &|_, _| {}).unwrap();
    // The roof edge (x = 12, 4 m) hides the ground up to where the ray through it lands; within
    // a cell of that line a ground cell's own pixels straddle the edge, which neither the DEM
    // nor the image resolves.
    let shadow_end = 12.0 + 4.0 * (12.0 - centre.x) / (centre.z - 4.0);
    let (mut red_outside, mut hidden_painted, mut roof_ok, mut roof) = (0, 0, 0, 0);
    for r in 0..80 {
        for c in 0..80 {
            let (x, y) = lattice.cell_center(c, r);
            let i = 4 * (r * 80 + c);
            let px = &ortho.rgba[i..i + 4];
            let red = px[3] == 255 && px[0] > 200 && px[1] < 60;
            if inside(x, y) {
                roof += 1;
                roof_ok += red as usize;
            } else if red && (x - shadow_end).abs() > 0.15 {
                red_outside += 1;
            }
            // Ground east of the box within the shadow of its roof edge (4 m high, the camera
            // 18 m up, 20 m west): hidden for about 4 × 20 / 14 ≈ 5.7 m.
            if (12.5..16.0).contains(&x) && (9.0..11.0).contains(&y) && px[3] == 255 {
                hidden_painted += 1;
            }
        }
    }
    assert!(roof_ok as f64 > 0.95 * roof as f64, "{roof_ok} of {roof}");
    assert_eq!(red_outside, 0, "the roof is mapped onto the ground");
    assert_eq!(hidden_painted, 0, "hidden ground is painted");
}

#[test]
fn bad_inputs_are_errors() {
    let lattice = Lattice::new(0.0, 20.0, 0.25, 8, 8).unwrap();
    let view = OrthoView {
        camera: camera(),
        cam_from_world: nadir(1.0, 19.0, 10.0),
    };
    let images = Images(Vec::new());
    let o = OrthoOptions::default();
    let e = |h: &[f32], v: &[OrthoView]| {
        orthomosaic(h, &lattice, v, &images, &o, &|_, _| {}).unwrap_err()
    };
    assert!(
        e(&[0.0; 3], std::slice::from_ref(&view))
            .to_string()
            .contains("3 heights")
    );
    assert!(e(&[0.0; 64], &[]).to_string().contains("no oriented image"));
    assert!(
        e(&[f32::NAN; 64], std::slice::from_ref(&view))
            .to_string()
            .contains("no height")
    );
    // The image provider's failure names the view.
    assert!(e(&[0.0; 64], &[view]).to_string().contains("view 0"));
}
