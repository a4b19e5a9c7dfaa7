//! The GeoTIFFs timesift writes, as GDAL (what QGIS and every GIS user opens them with) reads
//! them: CRS, nodata, 256 × 256 tiles, Deflate, internal overviews, no warning. Skips with a
//! printed reason where Debian's `gdal-bin` is not installed (`.ci/run` installs it).

use std::path::Path;
use std::process::Command;

use timesift_io::coords::Crs;
use timesift_io::geotiff::{GeoRaster, GeoReference, GeoTransform, write_f32, write_rgb8};

fn gdalinfo(path: &Path) -> Option<(String, String)> {
    let out = Command::new("gdalinfo").arg(path).output().ok()?;
    assert!(
        out.status.success(),
        "gdalinfo failed on {}",
        path.display()
    );
    Some((
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    ))
}

fn georef(nodata: Option<f64>) -> GeoReference {
    GeoReference {
        transform: GeoTransform {
            origin_x: 731_400.0,
            origin_y: 5_705_600.0,
            pixel_width: 0.05,
            pixel_height: -0.05,
        },
        crs: Crs::Epsg(32754),
        nodata,
        pixel_is_point: false,
    }
}

#[test]
fn gdal_reads_crs_nodata_tiles_and_overviews_without_warnings() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (900, 610);
    let dem = GeoRaster {
        width: w,
        height: h,
        bands: 1,
        data: (0..w * h)
            .map(|i| {
                if i % 97 == 0 {
                    -32767.0
                } else {
                    12.0 + ((i % w) as f32 * 0.01).sin()
                }
            })
            .collect(),
        georef: georef(Some(-32767.0)),
    };
    let dem_path = dir.path().join("dem.tif");
    write_f32(&dem_path, &dem).unwrap();
    let ortho = GeoRaster {
        width: w,
        height: h,
        bands: 4,
        data: (0..w * h * 4).map(|i| (i % 253) as u8).collect(),
        georef: georef(None),
    };
    let ortho_path = dir.path().join("ortho.tif");
    write_rgb8(&ortho_path, &ortho).unwrap();

    let Some((dem_info, dem_err)) = gdalinfo(&dem_path) else {
        println!("skipped: gdalinfo (Debian gdal-bin) is not installed");
        return;
    };
    for expect in [
        "Size is 900, 610",
        "32754",
        "Origin = (731400.000000000000000,5705600.000000000000000)",
        "Pixel Size = (0.050000000000000,-0.050000000000000)",
        "Block=256x256 Type=Float32",
        "NoData Value=-32767",
        "Overviews: 450x305, 225x153",
        "COMPRESSION=DEFLATE",
        "PREDICTOR=3",
    ] {
        assert!(dem_info.contains(expect), "{expect} not in:\n{dem_info}");
    }
    assert!(dem_err.trim().is_empty(), "gdalinfo warned: {dem_err}");

    let (ortho_info, ortho_err) = gdalinfo(&ortho_path).unwrap();
    for expect in [
        "Band 1 Block=256x256 Type=Byte, ColorInterp=Red",
        "Band 4 Block=256x256 Type=Byte, ColorInterp=Alpha",
        "Overviews: 450x305, 225x153",
        "COMPRESSION=DEFLATE",
    ] {
        assert!(
            ortho_info.contains(expect),
            "{expect} not in:\n{ortho_info}"
        );
    }
    assert!(ortho_err.trim().is_empty(), "gdalinfo warned: {ortho_err}");
}
