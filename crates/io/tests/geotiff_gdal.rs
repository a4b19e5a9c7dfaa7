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

/// An orthomosaic written a band of rows at a time makes the file the whole-raster writer makes,
/// leaves no spool file behind, and as BigTIFF (what files over 4 GiB become) GDAL reads it as
/// it reads the classic one.
#[test]
fn a_raster_streamed_by_bands_and_as_big_tiff_reads_in_gdal() {
    use timesift_io::geotiff::GeoTiffWriter;
    use timesift_io::tiled_tiff::{Pixels, SampleFormat};
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (700, 530);
    let data: Vec<u8> = (0..w * h * 4).map(|i| (i * 5 % 251) as u8).collect();
    let whole_path = dir.path().join("whole.tif");
    write_rgb8(
        &whole_path,
        &GeoRaster {
            width: w,
            height: h,
            bands: 4,
            data: data.clone(),
            georef: georef(None),
        },
    )
    .unwrap();
    let stream = |name: &str, big: bool| {
        let path = dir.path().join(name);
        let mut writer =
            GeoTiffWriter::create(&path, w, h, SampleFormat::U8 { bands: 4 }, &georef(None))
                .unwrap();
        if big {
            writer = writer.big_tiff();
        }
        for band in data.chunks(w * 4 * 100) {
            writer
                .push_rows(Pixels::U8 {
                    data: band,
                    bands: 4,
                })
                .unwrap();
        }
        writer.finish().unwrap();
        path
    };
    let streamed = stream("streamed.tif", false);
    assert!(std::fs::read(&streamed).unwrap() == std::fs::read(&whole_path).unwrap());
    let big = stream("big.tif", true);
    let mut left: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["big.tif", "streamed.tif", "whole.tif"]);

    // A writer dropped before it is finished leaves neither a file nor its spool.
    let abandoned = dir.path().join("abandoned.tif");
    let mut writer = GeoTiffWriter::create(
        &abandoned,
        w,
        h,
        SampleFormat::U8 { bands: 4 },
        &georef(None),
    )
    .unwrap();
    writer
        .push_rows(Pixels::U8 {
            data: &data[..w * 4 * 300],
            bands: 4,
        })
        .unwrap();
    drop(writer);
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);

    let Some((info, err)) = gdalinfo(&big) else {
        println!("skipped: gdalinfo (Debian gdal-bin) is not installed");
        return;
    };
    for expect in [
        "Size is 700, 530",
        "32754",
        "Band 4 Block=256x256 Type=Byte, ColorInterp=Alpha",
        "Overviews: 350x265",
        "COMPRESSION=DEFLATE",
    ] {
        assert!(info.contains(expect), "{expect} not in:\n{info}");
    }
    assert!(err.trim().is_empty(), "gdalinfo warned: {err}");
    // The same raster: GDAL's checksums of every band and overview agree.
    let checksums = |text: &str| -> Vec<String> {
        text.lines()
            .filter(|l| l.contains("Checksum="))
            .map(str::to_string)
            .collect()
    };
    let with_checksums = |path: &Path| {
        let out = Command::new("gdalinfo")
            .args(["-checksum"])
            .arg(path)
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let (a, b) = (with_checksums(&big), with_checksums(&streamed));
    assert_eq!(checksums(&a).len(), 4);
    assert_eq!(checksums(&a), checksums(&b));
}
