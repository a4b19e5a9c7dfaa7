//! Depth maps and fused clouds of rendered scenes against their exact geometry: a plane under a
//! nadir block and a sphere seen from a ring, both recovered to sub-pixel depth error.

mod common;

use std::collections::HashSet;

use common::Rendered;
use nalgebra::Vector3;
use timesift_dense::{DenseOptions, FusedCloud, reconstruct_epoch};

/// Depth errors of the final maps expressed in pixel footprints (|δz| · f / z, the depth error
/// over the size of a pixel on the surface), and the fraction of usable pixels with a depth.
struct MapErrors {
    median: f64,
    p90: f64,
    filled: f64,
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn map_errors(r: &Rendered, options: &DenseOptions) -> (MapErrors, MapErrors) {
    let views = r.views();
    let masks = vec![None; views.len()];
    let result = reconstruct_epoch(&r.input, &views, &masks, options).expect("dense");
    let (plan, maps, cloud) = (&result.plan, &result.filtered, &result.cloud);
    let mut errors = Vec::new();
    let (mut with_depth, mut total) = (0usize, 0usize);
    for (view, (vp, map)) in plan.views.iter().zip(maps).enumerate() {
        let cam = vp.camera;
        for j in 0..map.height {
            for i in 0..map.width {
                let Some(truth) = r.true_depth(view, &cam, i as f64 + 0.5, j as f64 + 0.5) else {
                    continue;
                };
                total += 1;
                let d = map.depth[j * map.width + i] as f64;
                if d > 0.0 {
                    with_depth += 1;
                    errors.push((d - truth).abs() * cam.f / truth);
                }
            }
        }
    }
    let maps = MapErrors {
        median: quantile(&mut errors, 0.5),
        p90: quantile(&mut errors, 0.9),
        filled: with_depth as f64 / total as f64,
    };
    // Fused points: distance to the true surface in pixel footprints of the nearest camera.
    let f = plan.views[0].camera.f;
    let mut cloud_errors: Vec<f64> = cloud
        .positions
        .iter()
        .map(|p| r.surface_error_px(p, f))
        .collect();
    // Points from two images only where no third image has the ground in its field (the
    // images less a border of 3 % of their width: the working cameras' undistorted fields
    // differ from the images' by a few pixels).
    let inset = 0.03 * r.size.0 as f64;
    for (p, &n) in cloud.positions.iter().zip(&cloud.images) {
        assert!(n >= 2, "a point from one image");
        if n < 3 {
            let seeing = r.views_with_in_field(p, inset);
            assert!(
                seeing <= 2,
                "a 2-image point where {seeing} views have it in their field"
            );
        }
    }
    let fused = MapErrors {
        median: quantile(&mut cloud_errors, 0.5),
        p90: quantile(&mut cloud_errors, 0.9),
        filled: cloud.len() as f64,
    };
    (maps, fused)
}

fn options(level: u32) -> DenseOptions {
    let mut o = DenseOptions::default();
    o.plan.level = level;
    o
}

#[test]
fn a_plane_is_recovered_to_sub_pixel_depth() {
    let scene = common::plane(240, 180);
    let (maps, fused) = map_errors(&scene, &options(1));
    println!(
        "plane maps: median {:.3} px, p90 {:.3} px, filled {:.3}; fused: median {:.3}, p90 {:.3}, {} points",
        maps.median, maps.p90, maps.filled, fused.median, fused.p90, fused.filled
    );
    assert!(maps.median < 0.2 && maps.p90 < 1.0 && maps.filled > 0.8);
    assert!(fused.median < 0.2 && fused.p90 < 0.6 && fused.filled > 5_000.0);
}

#[test]
fn a_sphere_is_recovered_to_sub_pixel_depth() {
    let scene = common::sphere(240, 180);
    let (maps, fused) = map_errors(&scene, &options(1));
    println!(
        "sphere maps: median {:.3} px, p90 {:.3} px, filled {:.3}; fused: median {:.3}, p90 {:.3}, {} points",
        maps.median, maps.p90, maps.filled, fused.median, fused.p90, fused.filled
    );
    // Depth along the ray: grazing parts of the sphere turn a small distance into a longer one.
    assert!(maps.median < 0.5 && maps.p90 < 1.0 && maps.filled > 0.75);
    assert!(fused.median < 0.25 && fused.p90 < 0.6 && fused.filled > 10_000.0);
}

/// Heights of a fused cloud gridded as a DEM (median per cell of `cell` metres), against the
/// truth: (mean signed error over the cells on crowns, points per m² on the ground away from
/// them).
fn crown_dem(r: &Rendered, options: &DenseOptions, cell: f64) -> (f64, f64, usize) {
    let views = r.views();
    let masks = vec![None; views.len()];
    let result = reconstruct_epoch(&r.input, &views, &masks, options).expect("dense");
    let cloud = &result.cloud;
    let (x0, y0, size) = (-4.0, -3.0, ((8.0 / cell) as usize, (6.0 / cell) as usize));
    let mut cells: Vec<Vec<f64>> = vec![Vec::new(); size.0 * size.1];
    let mut ground_points = 0usize;
    for p in &cloud.positions {
        let (i, j) = ((p.x - x0) / cell, (p.y - y0) / cell);
        if i < 0.0 || j < 0.0 || i >= size.0 as f64 || j >= size.1 as f64 {
            continue;
        }
        cells[j as usize * size.0 + i as usize].push(p.z);
        if !common::near_crown(p.x, p.y, 0.5) {
            ground_points += 1;
        }
    }
    let mut errors = Vec::new();
    let mut ground_cells = 0usize;
    for j in 0..size.1 {
        for i in 0..size.0 {
            let (x, y) = (x0 + (i as f64 + 0.5) * cell, y0 + (j as f64 + 0.5) * cell);
            let mut zs = std::mem::take(&mut cells[j * size.0 + i]);
            if !common::near_crown(x, y, 0.5) {
                ground_cells += 1;
            }
            if zs.is_empty() || !common::near_crown(x, y, 0.0) {
                continue;
            }
            errors.push(quantile(&mut zs, 0.5) - common::crown_height(x, y));
        }
    }
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let density = ground_points as f64 / (ground_cells as f64 * cell * cell);
    (mean, density, errors.len())
}

#[test]
fn refinement_at_twice_the_resolution_measures_narrow_crowns_and_keeps_the_ground_density() {
    let scene = common::crowns(320, 240);
    // At level 2 a pixel covers 7.8 cm; the DEM cell is two of them.
    let cell = 0.16;
    let mut plain = options(2);
    plain.plan.refine = false;
    let refined = options(2);
    let (mean_plain, density_plain, cells_plain) = crown_dem(&scene, &plain, cell);
    let (mean_refined, density_refined, cells_refined) = crown_dem(&scene, &refined, cell);
    println!(
        "crowns: mean height error {mean_plain:+.3} m over {cells_plain} cells at level 2, \
         {mean_refined:+.3} m over {cells_refined} cells refined; ground points per m² \
         {density_plain:.1} and {density_refined:.1}"
    );
    assert!(
        mean_refined.abs() < 0.5 * mean_plain.abs(),
        "refinement should at least halve the crowns' bias"
    );
    assert!(
        (density_refined / density_plain - 1.0).abs() < 0.2,
        "flat ground keeps the level's density"
    );
}

/// The stage's promise that its products do not depend on the number of threads: the
/// propagation's checkerboard, the filter's rows and the fusion's order each keep it.
#[test]
fn maps_filtering_and_fusion_give_the_same_result_on_any_number_of_threads() {
    let scene = common::plane(160, 120);
    let views = scene.views();
    let masks = vec![None; views.len()];
    let on = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool")
            .install(|| reconstruct_epoch(&scene.input, &views, &masks, &options(1)))
            .expect("dense")
    };
    let one = on(1);
    assert!(
        one.filtered.iter().any(|m| m.valid_count() > 0) && one.cloud.len() > 1_000,
        "the scene must give depths to compare: {} points",
        one.cloud.len()
    );
    assert!(one == on(3), "3 threads gave another result than 1");
}

/// Ground that only two images have in their field (a strip's ends, the bands between every
/// other image) is fused from those two with `fill_edges`, about as accurately as the rest;
/// without it none of it is, and where three or more images see the ground no less is fused.
#[test]
fn ground_that_only_two_images_see_is_fused_from_both_with_fill_edges() {
    // A strip of four images 5 m apart, 10 m up, each 12.5 m wide on the ground: bands of
    // two, three and two images across it, and two images at each end.
    let cameras = [-7.5, -2.5, 2.5, 7.5].map(|x| (x, 0.0, x));
    let scene = common::plane_under(160, 120, &cameras);
    let views = scene.views();
    let masks = vec![None; views.len()];
    let run = |fill_edges: bool| {
        let mut o = options(1);
        o.filter.fill_edges = fill_edges;
        o.fusion.fill_edges = fill_edges;
        reconstruct_epoch(&scene.input, &views, &masks, &o).expect("dense")
    };
    let (strict, filled) = (run(false), run(true));
    let f = filled.plan.views[0].camera.f;
    let (strict, filled) = (strict.cloud, filled.cloud);
    // Cells of 0.25 m over the ground: those that two images have clearly in their field (5 %
    // of the width inside their borders, beyond the matching window's reach) and no other even
    // 5 % beyond its border, and those that three or more have clearly.
    let cell = 0.25;
    let key = |p: &Vector3<f64>| ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
    let inset = 0.05 * scene.size.0 as f64;
    let (mut two, mut more) = (Vec::new(), Vec::new());
    for a in -64..64 {
        for b in -24..24 {
            let (x, y) = (
                500_000.0 + cell * (a as f64 + 0.5),
                5_000_000.0 + cell * (b as f64 + 0.5),
            );
            let Some(ground) = scene
                .scene
                .hit(&Vector3::new(x, y, 1_000.0), &Vector3::new(0.0, 0.0, -1.0))
            else {
                continue;
            };
            if scene.views_with_in_field(&ground, -inset) == 2
                && scene.views_with_in_field(&ground, inset) == 2
            {
                two.push(key(&ground));
            } else if scene.views_with_in_field(&ground, inset) >= 3 {
                more.push(key(&ground));
            }
        }
    }
    assert!(
        two.len() > 500 && more.len() > 200,
        "{} / {} cells",
        two.len(),
        more.len()
    );
    let covered = |cloud: &FusedCloud, cells: &[(i64, i64)]| {
        let occupied: HashSet<(i64, i64)> = cloud.positions.iter().map(key).collect();
        cells.iter().filter(|c| occupied.contains(c)).count() as f64 / cells.len() as f64
    };
    let (strict_two, filled_two) = (covered(&strict, &two), covered(&filled, &two));
    let (strict_more, filled_more) = (covered(&strict, &more), covered(&filled, &more));
    let mut pair_errors: Vec<f64> = filled
        .positions
        .iter()
        .zip(&filled.images)
        .filter(|(_, n)| **n == 2)
        .map(|(p, _)| scene.surface_error_px(p, f))
        .collect();
    let pairs = pair_errors.len();
    assert!(pairs > 0, "fill_edges fused no point from two images");
    let (median, p90) = (
        quantile(&mut pair_errors, 0.5),
        quantile(&mut pair_errors, 0.9),
    );
    println!(
        "ground seen by two images: {strict_two:.3} covered strict, {filled_two:.3} with fill_edges \
         ({pairs} 2-image points, median {median:.3} px, p90 {p90:.3} px); by three or more: \
         {strict_more:.3} / {filled_more:.3}"
    );
    assert!(
        strict.images.iter().all(|&n| n >= 3),
        "strict: a point from 2 images"
    );
    assert!(
        strict_two < 0.1,
        "strict fusion covers ground two images see: {strict_two}"
    );
    assert!(
        filled_two > 0.8,
        "fill_edges leaves ground two images see empty: {filled_two}"
    );
    assert!(
        filled_more >= strict_more - 0.005,
        "{filled_more} < {strict_more}"
    );
    assert!(
        median < 0.3 && p90 < 1.0,
        "2-image points: median {median}, p90 {p90}"
    );
}
