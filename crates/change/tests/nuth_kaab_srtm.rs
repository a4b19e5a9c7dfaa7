//! Nuth & Kääb on the demcompare SRTM pair: the secondary DEM is the reference blurred and cropped
//! so that its cell (c, r) shows the reference's cell (c + 3, r + 5) (data_description.md there).

use std::path::PathBuf;

use timesift_change::dod::dem_of_difference;
use timesift_change::grid::Dem;
use timesift_change::nuth_kaab::{NuthKaabOptions, nuth_kaab};
use timesift_change::stats::statistics;
use timesift_io::geotiff::read_f32;

fn srtm(name: &str) -> Dem {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/demcompare-srtm/input")
        .join(name);
    let raster = read_f32(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    Dem::from_raster(raster, None).expect("dem")
}

#[test]
fn finds_the_three_five_pixel_shift() {
    let reference = srtm("srtm_ref.tif");
    let secondary = srtm("srtm_blurred_and_shifted.tif");
    let result = nuth_kaab(&reference, &secondary, None, &NuthKaabOptions::default()).expect("fit");
    eprintln!("{result:#?}");
    // Moving the secondary by +3 columns and +5 rows puts its content back over the reference.
    assert!(result.converged);
    assert!(
        (result.shift_px[0] - 3.0).abs() < 0.05,
        "{:?}",
        result.shift_px
    );
    assert!(
        (result.shift_px[1] - 5.0).abs() < 0.05,
        "{:?}",
        result.shift_px
    );
    assert!(result.nmad_after < 0.1 * result.nmad_before);

    // The aligned DEM, differenced on the reference grid, has lost the slope-correlated error.
    let aligned = result.apply(&secondary);
    let before = statistics(
        dem_of_difference(&reference, &secondary)
            .expect("dod")
            .values
            .iter()
            .map(|&v| v as f64),
    )
    .expect("stats");
    let after = statistics(
        dem_of_difference(&reference, &aligned)
            .expect("dod")
            .values
            .iter()
            .map(|&v| v as f64),
    )
    .expect("stats");
    assert!(
        after.nmad < 0.1 * before.nmad,
        "{} → {}",
        before.nmad,
        after.nmad
    );
    assert!(after.median.abs() < 0.5, "{}", after.median);
}
