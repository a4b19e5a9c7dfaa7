//! Copies a single-band GeoTIFF through timesift's reader and writer, so the output can be checked
//! with other tools (`gdalinfo`): `cargo run -p timesift-io --example geotiff_copy -- IN OUT [NODATA]`.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let (Some(input), Some(output)) = (args.next(), args.next()) else {
        return Err("usage: geotiff_copy IN OUT [NODATA]".into());
    };
    let mut raster = timesift_io::geotiff::read_f32(&PathBuf::from(input))?;
    if let Some(nodata) = args.next() {
        raster.georef.nodata = Some(nodata.parse()?);
    }
    timesift_io::geotiff::write_f32(&PathBuf::from(&output), &raster)?;
    println!("wrote {output}");
    Ok(())
}
