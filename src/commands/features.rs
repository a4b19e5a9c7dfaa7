//! `timesift features`: keypoints and descriptors of one image, in the text format of docs/design.md,
//! so that features can be inspected and compared outside timesift.

use std::path::{Path, PathBuf};

use anyhow::Context;
use timesift_features::{
    DetectorOptions, FeatureExtractor, Features, GreyImage, KeypointLimit, LdbExtractor, Mask,
    Orientation, SiftExtractor, SiftNormalization, Upsample,
};

/// The descriptor to compute.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// SIFT, 128 floats (Lowe 2004).
    Sift,
    /// RootSIFT: SIFT mapped so that Euclidean distance compares like the Hellinger kernel.
    Rootsift,
    /// LDB, 486 bits in 61 bytes, compared by Hamming distance.
    Ldb,
}

/// What `timesift features` was asked for (also its command-line arguments).
#[derive(Debug, Clone, clap::Args)]
pub struct FeaturesRequest {
    /// The image (JPEG, PNG or TIFF; colour is converted to grey).
    pub image: PathBuf,
    /// Descriptor.
    #[arg(long, value_enum, default_value = "sift")]
    pub method: Method,
    /// Keep at most this many keypoints, strongest first, spread over the image.
    #[arg(long)]
    pub max: Option<usize>,
    /// Grey image of the same size; keypoints only where it is non-zero.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Orientation 0 for every keypoint (images that share their rotation).
    #[arg(long)]
    pub upright: bool,
    /// Whether the first octave doubles the image (default: images up to 30 MP).
    #[arg(long)]
    pub upsample: Option<bool>,
    /// Output text file.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the extraction and writes the text file; returns the features.
pub fn features(request: &FeaturesRequest) -> anyhow::Result<Features> {
    let image = timesift_io::image::read_grey(&request.image)?;
    let grey = GreyImage::from_io(&image).with_context(|| request.image.display().to_string())?;
    let mask_pixels = match request.mask.as_deref() {
        Some(path) => {
            let (w, h, data) = read_mask(path)?;
            if (w, h) != (grey.width(), grey.height()) {
                anyhow::bail!(
                    "mask {} is {w} × {h} px but the image {} is {} × {} px",
                    path.display(),
                    request.image.display(),
                    grey.width(),
                    grey.height()
                );
            }
            Some((w, h, data))
        }
        None => None,
    };
    let mask = match &mask_pixels {
        Some((w, h, data)) => Some(Mask::new(*w, *h, data)?),
        None => None,
    };
    let detector = DetectorOptions {
        orientation: if request.upright {
            Orientation::Upright
        } else {
            DetectorOptions::default().orientation
        },
        upsample: match request.upsample {
            Some(true) => Upsample::Always,
            Some(false) => Upsample::Never,
            None => DetectorOptions::default().upsample,
        },
        limit: request.max.map(KeypointLimit::spread),
        ..DetectorOptions::default()
    };
    let extractor: Box<dyn FeatureExtractor> = match request.method {
        Method::Sift => Box::new(SiftExtractor {
            detector,
            normalization: SiftNormalization::L2,
        }),
        Method::Rootsift => Box::new(SiftExtractor {
            detector,
            normalization: SiftNormalization::Root,
        }),
        Method::Ldb => Box::new(LdbExtractor { detector }),
    };
    let features = extractor
        .extract(&grey, mask.as_ref())
        .with_context(|| request.image.display().to_string())?;
    timesift_features::text::write(&request.out, &features)?;
    Ok(features)
}

fn read_mask(path: &Path) -> anyhow::Result<(usize, usize, Vec<u8>)> {
    let mask = timesift_io::image::read_grey(path)?;
    Ok((
        mask.width as usize,
        mask.height as usize,
        mask.data.iter().map(|&v| u8::from(v > 0.0)).collect(),
    ))
}
