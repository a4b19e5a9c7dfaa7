//! OpenEXR float output for depth, normal and confidence maps.

use std::path::Path;

use exr::prelude::*;

use crate::{IoError, fsutil};

/// Writes named f32 channels of one `width × height` image to an EXR file (ZIP-compressed,
/// lossless). Each channel holds `width * height` row-major values.
pub fn write_f32_channels(
    path: &Path,
    width: usize,
    height: usize,
    channels: &[(&str, &[f32])],
) -> std::result::Result<(), IoError> {
    if channels.is_empty() {
        return Err(IoError::invalid(path, "no channel to write"));
    }
    let mut list = SmallVec::<[AnyChannel<FlatSamples>; 4]>::new();
    for (name, data) in channels {
        if data.len() != width * height {
            return Err(IoError::invalid(
                path,
                format!(
                    "channel {name} holds {} values, expected {width}x{height}",
                    data.len()
                ),
            ));
        }
        list.push(AnyChannel::new(*name, FlatSamples::F32(data.to_vec())));
    }
    let layer = Layer::new(
        (width, height),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list),
    );
    let tmp = fsutil::temporary_sibling(path);
    let written = Image::from_layer(layer)
        .write()
        .to_file(&tmp)
        .map_err(|e| IoError::invalid(path, format!("cannot write EXR: {e}")));
    fsutil::commit_temporary(&tmp, path, written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_map_round_trips_through_exr() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("depth.exr");
        let depth: Vec<f32> = (0..12).map(|i| i as f32 * 1.5).collect();
        write_f32_channels(&p, 4, 3, &[("Z", &depth)]).unwrap();
        let image = read_first_flat_layer_from_file(&p).unwrap();
        let ch = &image.layer_data.channel_data.list[0];
        assert_eq!(ch.name, Text::from("Z"));
        match &ch.sample_data {
            FlatSamples::F32(v) => assert_eq!(v, &depth),
            other => panic!("unexpected samples {other:?}"),
        }
    }
}
