//! Coordinate reference systems: the project's CRS string and WGS84 ↔ projected transforms (UTM and
//! any EPSG-coded projected CRS known to `proj4rs`), used to turn EXIF GPS into camera-centre priors.

use std::fmt;
use std::str::FromStr;

use proj4rs::Proj;
use proj4rs::transform::{Transform, TransformClosure, transform};

use crate::IoError;

/// The project's world frame: an EPSG-coded projected CRS, or a local metric frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Crs {
    /// A local right-handed metric frame with no geodetic meaning.
    Local,
    /// An EPSG code.
    Epsg(u16),
}

impl Crs {
    /// The EPSG code, when there is one.
    pub fn epsg(self) -> Option<u16> {
        match self {
            Crs::Epsg(code) => Some(code),
            Crs::Local => None,
        }
    }

    /// The CRS's definition as OGC WKT 1, when the EPSG code is known.
    pub fn wkt(self) -> Option<&'static str> {
        self.epsg()
            .and_then(crs_definitions::from_code)
            .map(|d| d.wkt)
    }

    /// Whether the CRS is geographic (degrees) rather than projected (metres).
    pub fn is_geographic(self) -> bool {
        self.epsg()
            .and_then(crs_definitions::from_code)
            .is_some_and(|d| d.proj4.contains("+proj=longlat"))
    }
}

impl fmt::Display for Crs {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Crs::Local => write!(f, "local"),
            Crs::Epsg(code) => write!(f, "EPSG:{code}"),
        }
    }
}

impl FromStr for Crs {
    type Err = String;

    /// Parses `"local"` or `"EPSG:<code>"` (case-insensitive).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        if s.eq_ignore_ascii_case("local") {
            return Ok(Crs::Local);
        }
        let code = s
            .split_once(':')
            .filter(|(auth, _)| auth.eq_ignore_ascii_case("EPSG"))
            .and_then(|(_, code)| code.trim().parse::<u16>().ok())
            .ok_or_else(|| format!("expected \"local\" or \"EPSG:<code>\", got \"{s}\""))?;
        Ok(Crs::Epsg(code))
    }
}

/// The EPSG code of the WGS84 UTM zone containing a position (with the Norway and Svalbard
/// exceptions of the UTM grid).
pub fn utm_epsg_for(latitude: f64, longitude: f64) -> u16 {
    let lon = ((longitude + 180.0).rem_euclid(360.0)) - 180.0;
    let mut zone = (((lon + 180.0) / 6.0).floor() as i32).clamp(0, 59) + 1;
    if (56.0..64.0).contains(&latitude) && (3.0..12.0).contains(&lon) {
        zone = 32;
    }
    if (72.0..84.0).contains(&latitude) {
        zone = match lon {
            l if (0.0..9.0).contains(&l) => 31,
            l if (9.0..21.0).contains(&l) => 33,
            l if (21.0..33.0).contains(&l) => 35,
            l if (33.0..42.0).contains(&l) => 37,
            _ => zone,
        };
    }
    let base = if latitude >= 0.0 { 32600 } else { 32700 };
    base + zone as u16
}

/// Transforms between WGS84 geographic coordinates and one projected CRS. Heights pass through
/// unchanged (both ends use the WGS84 ellipsoid).
pub struct Projector {
    crs: Crs,
    projected: Proj,
    geographic: Proj,
}

struct Xyz(f64, f64, f64);

impl Transform for Xyz {
    fn transform_coordinates<F: TransformClosure>(
        &mut self,
        f: &mut F,
    ) -> proj4rs::errors::Result<()> {
        let (x, y, z) = f(self.0, self.1, self.2)?;
        *self = Xyz(x, y, z);
        Ok(())
    }
}

impl Projector {
    /// A projector to `crs`, which must be an EPSG-coded projected CRS.
    pub fn new(crs: Crs) -> Result<Self, IoError> {
        let err = |message: &str| IoError::Crs {
            crs: crs.to_string(),
            message: message.to_string(),
        };
        let code = crs
            .epsg()
            .ok_or_else(|| err("a local frame has no geodetic transform"))?;
        let projected =
            Proj::from_epsg_code(code).map_err(|e| err(&format!("unknown EPSG code ({e})")))?;
        if projected.is_latlong() {
            return Err(err(
                "is geographic; the world frame must be a projected (metric) CRS",
            ));
        }
        let geographic = Proj::from_proj_string("+proj=longlat +datum=WGS84 +no_defs")
            .map_err(|e| err(&format!("cannot build WGS84 ({e})")))?;
        Ok(Projector {
            crs,
            projected,
            geographic,
        })
    }

    /// The target CRS.
    pub fn crs(&self) -> Crs {
        self.crs
    }

    /// WGS84 latitude/longitude (degrees) to projected easting/northing (metres).
    pub fn project(&self, latitude: f64, longitude: f64) -> Result<(f64, f64), IoError> {
        let mut p = Xyz(longitude.to_radians(), latitude.to_radians(), 0.0);
        transform(&self.geographic, &self.projected, &mut p).map_err(|e| IoError::Crs {
            crs: self.crs.to_string(),
            message: format!("cannot project ({latitude}, {longitude}): {e}"),
        })?;
        Ok((p.0, p.1))
    }

    /// Projected easting/northing (metres) to WGS84 latitude/longitude (degrees).
    pub fn unproject(&self, easting: f64, northing: f64) -> Result<(f64, f64), IoError> {
        let mut p = Xyz(easting, northing, 0.0);
        transform(&self.projected, &self.geographic, &mut p).map_err(|e| IoError::Crs {
            crs: self.crs.to_string(),
            message: format!("cannot unproject ({easting}, {northing}): {e}"),
        })?;
        Ok((p.1.to_degrees(), p.0.to_degrees()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crs_strings_parse_and_print() {
        assert_eq!("EPSG:32633".parse::<Crs>().unwrap(), Crs::Epsg(32633));
        assert_eq!("epsg: 4326".parse::<Crs>().unwrap(), Crs::Epsg(4326));
        assert_eq!("Local".parse::<Crs>().unwrap(), Crs::Local);
        assert!("UTM33".parse::<Crs>().is_err());
        assert_eq!(Crs::Epsg(32755).to_string(), "EPSG:32755");
        assert!(Crs::Epsg(4326).is_geographic());
        assert!(!Crs::Epsg(32633).is_geographic());
        assert!(Crs::Epsg(32633).wkt().unwrap().contains("UTM zone 33N"));
    }

    #[test]
    fn utm_zones_cover_both_hemispheres_and_exceptions() {
        assert_eq!(utm_epsg_for(55.7, 13.2), 32633);
        assert_eq!(utm_epsg_for(-38.77, 143.66), 32754);
        assert_eq!(utm_epsg_for(60.0, 5.0), 32632); // Norway
        assert_eq!(utm_epsg_for(78.0, 15.0), 32633); // Svalbard
        assert_eq!(utm_epsg_for(0.0, -180.0), 32601);
        assert_eq!(utm_epsg_for(-1.0, 179.9), 32760);
    }

    #[test]
    fn known_points_project_to_reference_values() {
        // Reference values computed with PROJ (pyproj 3.7, EPSG:4326 -> EPSG:326xx/327xx).
        let lund = Projector::new(Crs::Epsg(32633)).unwrap();
        let (e, n) = lund.project(334189.0 / 6000.0, 13.195388888889).unwrap();
        assert!(
            (e - 386581.5883).abs() < 2e-3 && (n - 6173962.8754).abs() < 2e-3,
            "{e} {n}"
        );
        // A southern-hemisphere zone round trip.
        let south = Projector::new(Crs::Epsg(32754)).unwrap();
        let (e, n) = south.project(-38.77, 143.66).unwrap();
        assert!(e > 500000.0 && n < 10_000_000.0 && n > 5_000_000.0);
        let (lat, lon) = south.unproject(e, n).unwrap();
        assert!((lat + 38.77).abs() < 1e-10 && (lon - 143.66).abs() < 1e-10);
    }

    #[test]
    fn geographic_and_local_frames_are_rejected_as_projection_targets() {
        assert!(Projector::new(Crs::Epsg(4326)).is_err());
        assert!(Projector::new(Crs::Local).is_err());
        assert!(Projector::new(Crs::Epsg(1)).is_err());
    }
}
