//! Real data: sandpyper `mar` beach DSMs (1 m, EPSG:32754, −10000 as undeclared nodata).

use std::path::PathBuf;

use timesift_change::grid::Dem;
use timesift_change::icp::{IcpOptions, icp, rotation_angle, select};
use timesift_io::geotiff::read_f32;

fn dsm(date: &str) -> Dem {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/sandpyper-mar/dsm")
        .join(format!("mar_{date}_dsm_resampled_1m.tif"));
    let raster = read_f32(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    Dem::from_raster(raster, Some(-10000.0)).expect("dem")
}

#[test]
fn icp_recovers_a_rigid_transform_with_a_changed_region_masked_out() {
    let target = dsm("20180601").to_points();
    assert!(target.len() > 50_000);
    let (xmin, xmax) = target
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p[0]), b.max(p[0])));
    let (ymin, ymax) = target
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p[1]), b.max(p[1])));
    // A changed region (a 2 m high deposit over a fifth of the width) exists only in the source.
    let changed = |p: &[f64; 3]| {
        let u = (p[0] - xmin) / (xmax - xmin);
        let v = (p[1] - ymin) / (ymax - ymin);
        (0.4..0.6).contains(&u) && (0.2..0.8).contains(&v)
    };
    let angle = 0.35f64.to_radians();
    let axis = nalgebra::Unit::new_normalize(nalgebra::Vector3::new(0.3, -0.5, 1.0));
    let rotation = nalgebra::Rotation3::from_axis_angle(&axis, angle);
    let centre = nalgebra::Vector3::new(0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 0.0);
    let shift = nalgebra::Vector3::new(0.42, -0.37, 0.25);
    let source: Vec<[f64; 3]> = target
        .iter()
        .map(|p| {
            let mut q = nalgebra::Vector3::from(*p);
            if changed(p) {
                q.z += 2.0;
            }
            let q = rotation * (q - centre) + centre + shift;
            [q.x, q.y, q.z]
        })
        .collect();
    // The stable mask is given in the target's frame; the source is masked where it stands.
    let stable_target: Vec<bool> = target.iter().map(|p| !changed(p)).collect();
    let stable_source: Vec<bool> = stable_target.clone();
    let r = icp(
        &select(&source, &stable_source),
        &select(&target, &stable_target),
        &IcpOptions::default(),
    )
    .expect("icp");
    eprintln!("{r:?}");
    assert!(r.converged);
    // Expected: the inverse transform.
    let inverse = rotation.inverse();
    let found = nalgebra::Matrix3::from_row_slice(&r.rotation.concat());
    let residual_deg = rotation_angle(&(found * rotation.matrix())).to_degrees();
    assert!(residual_deg < 0.01, "{}°", residual_deg);
    let expected_t = centre - inverse * (centre + shift);
    let t_err = (nalgebra::Vector3::from(r.translation) - expected_t).norm();
    eprintln!(
        "ICP on sandpyper 2018-06-01 ({} stable pairs): rotation error {:.2e}°, translation error {:.2e} m",
        r.pairs, residual_deg, t_err
    );
    assert!(t_err < 1e-3, "{t_err} m");
    // Every stable source point lands on its original within 1 mm.
    let worst = source
        .iter()
        .zip(&target)
        .zip(&stable_source)
        .filter(|(_, s)| **s)
        .map(|((s, t), _)| {
            let q = r.transform(s);
            ((q[0] - t[0]).powi(2) + (q[1] - t[1]).powi(2) + (q[2] - t[2]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "{worst}");
}
