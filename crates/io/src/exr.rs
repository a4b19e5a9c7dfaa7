//! OpenEXR float output for depth, normal and confidence maps.

use std::path::Path;

use exr::prelude::*;

use crate::{IoError, budget, fsutil};

/// Writes named f32 channels of one `width × height` image to an EXR file (run-length encoded
/// in tiles of 64 × 64: lossless). Each channel holds `width * height` row-major values.
///
/// Not ZIP: on depth and normal maps (noisy floats) it saved 8–10 % of the bytes for 6 of the
/// 64 CPU-seconds of the demo's dense stage, writing and reading the maps (35.5 → 32.0 s wall on
/// 2 cores); run-length encoding still shrinks the filtered maps' empty areas.
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
    let mut attributes = LayerAttributes::default();
    attributes.other.insert(
        Text::from(CHECKSUM_ATTRIBUTE),
        AttributeValue::Text(Text::from(checksum(channels.iter().copied()).as_str())),
    );
    let layer = Layer::new(
        (width, height),
        attributes,
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(list),
    );
    let tmp = fsutil::temporary_sibling(path);
    let written = Image::from_layer(layer)
        .write()
        .to_file(&tmp)
        .map_err(|e| IoError::invalid(path, format!("cannot write EXR: {e}")));
    fsutil::commit_temporary(&tmp, path, written)
}

/// The layer attribute holding [`checksum`]: run-length encoded samples decode from a damaged
/// file as other numbers without an error, and a map read back must be the map written.
const CHECKSUM_ATTRIBUTE: &str = "timesiftChecksum";

/// FNV-1a (64 bit) of the channels in name order: each name, then its samples' bits.
fn checksum<'a>(channels: impl Iterator<Item = (&'a str, &'a [f32])>) -> String {
    let mut sorted: Vec<(&str, &[f32])> = channels.collect();
    sorted.sort_by(|a, b| a.0.cmp(b.0));
    let mut hash = crate::fingerprint::Fnv1a::new();
    for (name, samples) in sorted {
        hash.write(name.as_bytes());
        for &v in samples {
            hash.write_f32(v);
        }
    }
    format!("fnv1a64:{}", hash.hex())
}

/// The f32 channels of one image.
#[derive(Debug, Clone, PartialEq)]
pub struct F32Channels {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Channels by name (in the file's sorted order), `width * height` row-major values each.
    pub channels: Vec<(String, Vec<f32>)>,
}

impl F32Channels {
    /// The channel called `name`, when it has one value per pixel.
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        self.channels
            .iter()
            .find(|(n, v)| n == name && v.len() == self.width * self.height)
            .map(|(_, v)| v.as_slice())
    }
}

/// Reads every f32 channel of an EXR file written by [`write_f32_channels`]. Other sample
/// types are an error naming the channel, and so are samples that differ from those written
/// (the checksum [`write_f32_channels`] records; files of other programs have none).
pub fn read_f32_channels(path: &Path) -> std::result::Result<F32Channels, IoError> {
    check_claimed_size(path)?;
    // A corrupt block can trip the exr crate's own assertions (a line of another resolution
    // level than the one read): an error naming the file, like any other corruption.
    let image = crate::decoder_guard::catch_decoder_panic(path, "the EXR decoder", || {
        read_first_flat_layer_from_file(path)
            .map_err(|e| IoError::invalid(path, format!("cannot read EXR: {e}")))
    })?;
    let recorded = match image
        .layer_data
        .attributes
        .other
        .get(&Text::from(CHECKSUM_ATTRIBUTE))
    {
        Some(AttributeValue::Text(t)) => Some(t.to_string()),
        _ => None,
    };
    let size = image.layer_data.size;
    let mut channels = Vec::new();
    for ch in image.layer_data.channel_data.list {
        let name = ch.name.to_string();
        match ch.sample_data {
            FlatSamples::F32(v) => channels.push((name, v)),
            _ => {
                return Err(IoError::invalid(
                    path,
                    format!("channel {name}: expected 32-bit float samples"),
                ));
            }
        }
    }
    if let Some(recorded) = recorded {
        let found = checksum(channels.iter().map(|(n, v)| (n.as_str(), v.as_slice())));
        if found != recorded {
            return Err(IoError::invalid(
                path,
                format!(
                    "checksum mismatch: the samples hash to {found}, the file recorded \
                     {recorded} (damaged after it was written)"
                ),
            ));
        }
    }
    Ok(F32Channels {
        width: size.width(),
        height: size.height(),
        channels,
    })
}

/// The most channels a map of timesift's has (depth, normal, confidence and a few more).
const MAX_CHANNELS: usize = 16;

/// Reads the headers alone and checks the sizes they claim (the exr crate allocates every
/// channel of the first layer, and a block's bytes as a block's header claims them up to the
/// largest block the layer can have, before reading a sample).
fn check_claimed_size(path: &Path) -> std::result::Result<(), IoError> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| IoError::invalid(path, format!("cannot read EXR: {e}")))?;
    let file_len = std::fs::metadata(path)
        .map_err(|e| IoError::io(path, e))?
        .len();
    // No compression of EXR's (deflate at best, about 1,032 to 1) makes more than this of the
    // file: a larger claim is a corrupt header, whatever memory there is.
    let justified = MAX_EXPANSION * file_len + (1 << 20);
    if meta.headers.is_empty() {
        return Err(IoError::invalid(path, "cannot read EXR: no layer"));
    }
    for (k, header) in meta.headers.iter().enumerate() {
        if header.deep {
            return Err(IoError::unsupported(path, "EXR layout", "deep data"));
        }
        let size = header.layer_size;
        let cells = budget::check_cells(path, size.0 as u64, size.1 as u64, "the EXR layer")?;
        let channels = header.channels.list.len();
        if channels > MAX_CHANNELS {
            return Err(IoError::invalid(
                path,
                format!(
                    "EXR layer {k} claims {channels} channels; at most {MAX_CHANNELS} are read"
                ),
            ));
        }
        let decoded = cells * 4 * channels as u64;
        let block = header.max_block_byte_size() as u64;
        if decoded > justified || block > justified {
            return Err(IoError::invalid(
                path,
                format!(
                    "EXR layer {k} claims {} × {} pixels of {channels} channels in blocks of up \
                     to {block} bytes, more than its {file_len} bytes can hold",
                    size.0, size.1
                ),
            ));
        }
        if k == 0 {
            budget::ensure_allocatable(path, decoded + block, "the EXR layer")?;
        }
    }
    Ok(())
}

/// The most bytes a byte of an EXR file decodes to (deflate's bound, with room).
const MAX_EXPANSION: u64 = 1100;

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
        let read = read_f32_channels(&p).unwrap();
        assert_eq!((read.width, read.height), (4, 3));
        assert_eq!(read.channel("Z"), Some(depth.as_slice()));
        assert_eq!(read.channel("Y"), None);
        // A flipped bit in the samples decodes without an error: the checksum tells.
        let mut bytes = std::fs::read(&p).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0x10;
        std::fs::write(&p, &bytes).unwrap();
        let err = read_f32_channels(&p).unwrap_err().to_string();
        assert!(err.contains("checksum mismatch"), "{err}");
        std::fs::write(&p, b"not exr").unwrap();
        assert!(
            read_f32_channels(&p)
                .unwrap_err()
                .to_string()
                .contains("depth.exr")
        );
    }
}
