//! GeoTIFF round trip on real drone DSMs and orthophotos (sandpyper `mar`, ../shared/data).

use std::path::PathBuf;

use timesift_io::coords::Crs;
use timesift_io::geotiff::{read_f32, read_grid, read_rgb8, write_f32, write_rgb8};

fn shared_data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
}

/// Also: the header alone read by `read_grid` is the full read's size and georeference.
#[test]
fn sandpyper_dsm_round_trip_is_identical() {
    let dir = tempfile::tempdir().unwrap();
    let dsm_dir = shared_data().join("sandpyper-mar/dsm");
    let mut count = 0;
    for entry in std::fs::read_dir(&dsm_dir).unwrap() {
        let src = entry.unwrap().path();
        let original = read_f32(&src).unwrap();
        // Facts from the files' own headers (gdalinfo): UTM 54S, about 1 m cells; 287 x 417 and
        // that exact pixel width for the first date.
        assert_eq!(original.georef.crs, Crs::Epsg(32754));
        assert!((original.georef.transform.pixel_width - 1.0).abs() < 0.01);
        if src.ends_with("mar_20180601_dsm_resampled_1m.tif") {
            assert_eq!((original.width, original.height), (287, 417));
            assert_eq!(original.georef.transform.pixel_width, 1.001249756097561);
            assert!((original.georef.transform.origin_x - 731413.76093).abs() < 1e-9);
        }
        // The header alone (what `timesift dem --like` reads) says the same as the full read.
        let grid = read_grid(&src).unwrap();
        assert_eq!((grid.width, grid.height), (original.width, original.height));
        assert_eq!(grid.georef, original.georef);
        let out = dir.path().join(src.file_name().unwrap());
        write_f32(&out, &original).unwrap();
        let back = read_f32(&out).unwrap();
        assert_eq!(back.georef, original.georef);
        assert_eq!(back.data.len(), original.data.len());
        assert!(
            back.data
                .iter()
                .zip(&original.data)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        count += 1;
    }
    assert_eq!(count, 9);
}

#[test]
fn sandpyper_dsm_with_nodata_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let src = shared_data().join("sandpyper-mar/dsm/mar_20180601_dsm_resampled_1m.tif");
    let mut dem = read_f32(&src).unwrap();
    // The source marks holes with -10000 but declares no nodata: declare the docs/design.md value.
    for v in dem.data.iter_mut().filter(|v| **v == -10000.0) {
        *v = -32767.0;
    }
    dem.georef.nodata = Some(-32767.0);
    let out = dir.path().join("dem.tif");
    write_f32(&out, &dem).unwrap();
    assert_eq!(read_f32(&out).unwrap(), dem);
}

#[test]
fn sandpyper_ortho_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let src = shared_data().join("sandpyper-mar/ortho/mar_20180601_ortho_resampled_1m.tif");
    let ortho = read_rgb8(&src).unwrap();
    assert_eq!(ortho.bands, 3);
    let out = dir.path().join("ortho.tif");
    write_rgb8(&out, &ortho).unwrap();
    assert_eq!(read_rgb8(&out).unwrap(), ortho);
}

#[test]
fn geographic_int16_srtm_is_read() {
    let src = shared_data().join("demcompare-srtm/input/srtm_ref.tif");
    let dem = read_f32(&src).unwrap();
    assert_eq!(dem.georef.crs, Crs::Epsg(4326));
    assert_eq!(dem.georef.nodata, Some(-32768.0));
    assert_eq!((dem.width, dem.height), (1000, 1000));
    assert!((dem.georef.transform.origin_x - 40.0).abs() < 1e-9);
}
