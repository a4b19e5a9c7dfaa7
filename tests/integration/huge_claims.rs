//! Files whose headers claim sizes they cannot hold (an image of 10¹⁰ pixels, a cloud of 4·10⁹
//! points, a raster of 4·10¹⁰ cells), read by the commands users run on such files, in a child
//! limited to 512 MiB of address space: each stops with one line naming the file, before it
//! allocates what the header claims (which would abort the child under the limit).

use std::path::Path;
use std::process::Command;

use timesift_io::coords::Crs;
use timesift_io::geotiff::{GeoRaster, GeoReference, GeoTransform};
use timesift_io::pointcloud::{LasWriteOptions, PointCloud};

/// `timesift ARGS` under a 512 MiB address-space limit: (success, standard error).
fn timesift_in_512_mib(args: &[&str]) -> (bool, String) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_timesift"));
    command.args(args);
    crate::common::output_with_limit(&mut command, libc::RLIMIT_AS, 512 << 20)
}

fn assert_one_line_naming(err: &str, file: &Path) {
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "not one line:\n{err}");
    assert!(
        lines[0].starts_with("error:") && lines[0].contains(&*file.to_string_lossy()),
        "{}",
        lines[0]
    );
    println!("{}", lines[0]);
}

/// CRC-32 (ISO-HDLC, PNG's) of `bytes`.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xffff_ffffu32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xedb8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// The value field of tag `tag` in the first IFD of a classic or Big TIFF, and its size in
/// bytes (2 for SHORT, 4 for LONG, 8 for LONG8), little-endian files only.
fn tiff_tag_value(bytes: &[u8], tag: u16) -> (usize, usize) {
    assert_eq!(&bytes[..2], b"II", "little-endian TIFF");
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let big = u16_at(2) == 43;
    let (ifd, count_len, entry_len, value_at) = if big {
        let o = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes")) as usize;
        (o, 8, 20, 12)
    } else {
        let o = u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes")) as usize;
        (o, 2, 12, 8)
    };
    let entries = if big {
        u64::from_le_bytes(bytes[ifd..ifd + 8].try_into().expect("8 bytes")) as usize
    } else {
        u16_at(ifd) as usize
    };
    for k in 0..entries {
        let e = ifd + count_len + k * entry_len;
        if u16_at(e) == tag {
            let size = match u16_at(e + 2) {
                3 => 2,
                4 => 4,
                16 => 8,
                t => panic!("tag {tag}: type {t}"),
            };
            return (e + value_at, size);
        }
    }
    panic!("no tag {tag}");
}

#[test]
fn headers_claiming_huge_sizes_fail_in_one_line_under_512_mib() {
    let tmp = tempfile::tempdir().expect("tempdir");

    // PNGs whose headers claim 100,000² pixels (beyond any raster timesift reads) and 40,000²
    // (within, but more than a file of 200 bytes can hold), their CRCs made right, so that
    // only the size is wrong.
    for side in [100_000u32, 40_000] {
        let png = tmp.path().join(format!("huge-{side}.png"));
        image::GrayImage::from_fn(64, 48, |x, y| image::Luma([(x * 3 + y) as u8]))
            .save(&png)
            .expect("png");
        let mut bytes = std::fs::read(&png).expect("read");
        assert_eq!(&bytes[12..16], b"IHDR");
        bytes[16..20].copy_from_slice(&side.to_be_bytes());
        bytes[20..24].copy_from_slice(&side.to_be_bytes());
        let crc = crc32(&bytes[12..29]);
        bytes[29..33].copy_from_slice(&crc.to_be_bytes());
        std::fs::write(&png, &bytes).expect("write");
        let keys = tmp.path().join("huge.txt");
        let (ok, err) = timesift_in_512_mib(&[
            "features",
            png.to_str().expect("utf-8"),
            "--out",
            keys.to_str().expect("utf-8"),
        ]);
        assert!(!ok, "features of a {side}² claim succeeded");
        assert_one_line_naming(&err, &png);
    }

    // A LAS file whose header claims 4,000,000,000 points.
    let las = tmp.path().join("huge.las");
    let cloud = PointCloud {
        positions: (0..100)
            .map(|k| [f64::from(k % 10), f64::from(k / 10), 1.0])
            .collect(),
        colors: None,
        attributes: Vec::new(),
        crs: Crs::Local,
    };
    timesift_io::pointcloud::write_las(&las, &cloud, &LasWriteOptions::default()).expect("las");
    let mut bytes = std::fs::read(&las).expect("read");
    // LAS 1.4: the legacy count (u32 at 107) and the count of point records (u64 at 247).
    bytes[107..111].copy_from_slice(&0u32.to_le_bytes());
    bytes[247..255].copy_from_slice(&4_000_000_000u64.to_le_bytes());
    std::fs::write(&las, &bytes).expect("write");
    let dem = tmp.path().join("dem.tif");
    let (ok, err) = timesift_in_512_mib(&[
        "dem",
        las.to_str().expect("utf-8"),
        "--cell",
        "1",
        "--out",
        dem.to_str().expect("utf-8"),
    ]);
    assert!(!ok, "a DEM of a 4·10⁹-point claim succeeded");
    assert_one_line_naming(&err, &las);

    // A GeoTIFF DEM whose tags claim 200,000 × 200,000 cells.
    let small = tmp.path().join("small.tif");
    let raster = GeoRaster {
        width: 32,
        height: 32,
        bands: 1,
        data: (0..32 * 32).map(|k| k as f32 * 0.01).collect(),
        georef: GeoReference {
            transform: GeoTransform {
                origin_x: 500_000.0,
                origin_y: 5_000_000.0,
                pixel_width: 1.0,
                pixel_height: -1.0,
            },
            crs: Crs::Epsg(32632),
            nodata: Some(-9999.0),
            pixel_is_point: false,
        },
    };
    timesift_io::geotiff::write_f32(&small, &raster).expect("tif");
    let huge = tmp.path().join("huge.tif");
    let mut bytes = std::fs::read(&small).expect("read");
    for tag in [256u16, 257] {
        let (at, size) = tiff_tag_value(&bytes, tag);
        let value = 200_000u64.to_le_bytes();
        bytes[at..at + size].copy_from_slice(&value[..size]);
    }
    std::fs::write(&huge, &bytes).expect("write");
    let out = tmp.path().join("compare");
    let (ok, err) = timesift_in_512_mib(&[
        "compare",
        small.to_str().expect("utf-8"),
        huge.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
    ]);
    assert!(!ok, "a comparison with a 4·10¹⁰-cell claim succeeded");
    assert_one_line_naming(&err, &huge);
}
