//! LAS/LAZ round trips keep points, colours, attributes and the CRS.

use timesift_io::coords::Crs;
use timesift_io::pointcloud::{
    AttributeValues, ExtraAttribute, LasWriteOptions, PointCloud, read_las, read_las_positions,
    write_las,
};

fn cloud(n: usize) -> PointCloud {
    // UTM-sized coordinates on a 1 mm lattice, so the LAS integers represent them exactly.
    let positions = (0..n)
        .map(|i| {
            [
                731413.0 + (i * 37 % 1000) as f64 * 0.001 + i as f64,
                5705142.0 + (i * 13 % 997) as f64 * 0.001,
                -2.5 + (i % 100) as f64 * 0.125,
            ]
        })
        .collect();
    PointCloud {
        positions,
        colors: Some(
            (0..n)
                .map(|i| [(i * 7 % 65536) as u16, 300, (i % 256) as u16 * 256])
                .collect(),
        ),
        attributes: vec![
            ExtraAttribute {
                name: "distance".into(),
                values: AttributeValues::F32((0..n).map(|i| i as f32 * -0.01).collect()),
            },
            ExtraAttribute {
                name: "lod95".into(),
                values: AttributeValues::F64((0..n).map(|i| 1.0 / (i + 1) as f64).collect()),
            },
            ExtraAttribute {
                name: "significant".into(),
                values: AttributeValues::U8((0..n).map(|i| (i % 2) as u8).collect()),
            },
        ],
        crs: Crs::Epsg(32754),
    }
}

fn assert_same(a: &PointCloud, b: &PointCloud) {
    assert_eq!(a.positions.len(), b.positions.len());
    for (p, q) in a.positions.iter().zip(&b.positions) {
        for k in 0..3 {
            assert!((p[k] - q[k]).abs() < 1e-6, "{p:?} vs {q:?}");
        }
    }
    assert_eq!(a.colors, b.colors);
    assert_eq!(a.attributes, b.attributes);
    assert_eq!(a.crs, b.crs);
}

#[test]
fn laz_and_las_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let c = cloud(5000);
    for name in ["dense.laz", "dense.las"] {
        let p = dir.path().join(name);
        write_las(&p, &c, &LasWriteOptions::default()).unwrap();
        assert_same(&read_las(&p).unwrap(), &c);
    }
    let las = std::fs::metadata(dir.path().join("dense.las"))
        .unwrap()
        .len();
    let laz = std::fs::metadata(dir.path().join("dense.laz"))
        .unwrap()
        .len();
    assert!(
        laz < las,
        "LAZ ({laz} B) must be compressed relative to LAS ({las} B)"
    );
}

#[test]
fn cloud_without_colour_or_crs() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = cloud(10);
    c.colors = None;
    c.attributes.clear();
    c.crs = Crs::Local;
    let p = dir.path().join("plain.laz");
    write_las(&p, &c, &LasWriteOptions::default()).unwrap();
    assert_same(&read_las(&p).unwrap(), &c);
}

#[test]
fn mismatched_attribute_length_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = cloud(10);
    c.attributes[0].values = AttributeValues::F32(vec![0.0; 3]);
    let p = dir.path().join("bad.laz");
    let e = write_las(&p, &c, &LasWriteOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad.laz"), "{e}");
    assert!(!p.exists());
}

#[test]
fn survey_wide_cloud_fits_at_millimetre_scale() {
    // 3 km wide: beyond what an offset at the minimum corner allows at 1 mm (±2147 m).
    let dir = tempfile::tempdir().unwrap();
    let mut c = cloud(3);
    c.positions = vec![
        [500000.0, 6000000.0, 10.0],
        [503000.0, 6003000.0, 12.0],
        [501500.0, 6001500.0, 11.0],
    ];
    let p = dir.path().join("wide.laz");
    write_las(&p, &c, &LasWriteOptions::default()).unwrap();
    assert_same(&read_las(&p).unwrap(), &c);
    // 5,000 km does not fit at 1 mm: a clear error, no file.
    c.positions[1][0] = 5_500_000.0;
    let e = write_las(
        &p.with_file_name("huge.laz"),
        &c,
        &LasWriteOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("too wide") && e.contains("huge.laz"), "{e}");
}

/// Positions alone (what DEM gridding reads): the same coordinates, bit for bit, as the full
/// read, from LAZ (the x, y, z layers decompressed alone, over several batches and chunks) and
/// from LAS; a truncated LAZ file, one whose header counts more points than its chunks hold, or
/// one whose LAZ items state other sizes than the decoder's, is an error naming it.
#[test]
fn positions_alone_are_the_full_read_s() {
    let dir = tempfile::tempdir().unwrap();
    let c = cloud(1_200_000);
    for name in ["big.laz", "big.las"] {
        let p = dir.path().join(name);
        write_las(&p, &c, &LasWriteOptions::default()).unwrap();
        let full = read_las(&p).unwrap();
        let positions = read_las_positions(&p).unwrap();
        assert!(positions.positions == full.positions, "{name}");
        assert_eq!(positions.crs, Crs::Epsg(32754));
        assert!(positions.colors.is_none() && positions.attributes.is_empty());
    }
    let bytes = std::fs::read(dir.path().join("big.laz")).unwrap();
    let cut = dir.path().join("cut.laz");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = read_las_positions(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.laz"), "{e}");
    // A header counting one point more than its 24 full chunks hold: an error, not a point
    // made of nothing (LAS 1.4 keeps the count twice: a u32 at byte 107, a u64 at byte 247).
    let mut more = bytes.clone();
    more[107..111].copy_from_slice(&1_200_001u32.to_le_bytes());
    more[247..255].copy_from_slice(&1_200_001u64.to_le_bytes());
    let over = dir.path().join("over.laz");
    std::fs::write(&over, &more).unwrap();
    let e = read_las_positions(&over).unwrap_err().to_string();
    assert!(e.contains("over.laz") && e.contains("1200001"), "{e}");
    // LAZ items that do not make the records the decoder lays out (the point item stated as 4
    // bytes, not 30): an error, not a misread or a panic. The laszip VLR's items follow its
    // 54-byte VLR header and 34 bytes of settings; the first item's size is its second u16.
    let vlr = bytes
        .windows(14)
        .position(|w| w == b"laszip encoded")
        .expect("a laszip VLR")
        - 2;
    let size_at = vlr + 54 + 34 + 2;
    assert_eq!(
        &bytes[size_at - 2..size_at + 2],
        &[10, 0, 30, 0],
        "Point14, 30 bytes"
    );
    let mut small = bytes.clone();
    small[size_at] = 4;
    let items = dir.path().join("items.laz");
    std::fs::write(&items, &small).unwrap();
    let e = read_las_positions(&items).unwrap_err().to_string();
    assert!(e.contains("items.laz") && e.contains("LAZ items"), "{e}");
}

/// An empty cloud reads back empty through the positions alone.
#[test]
fn positions_of_an_empty_cloud_are_none() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("empty.laz");
    write_las(&p, &cloud(0), &LasWriteOptions::default()).unwrap();
    assert!(read_las_positions(&p).unwrap().positions.is_empty());
}
