//! Well-known-text polygons (`POLYGON`, `MULTIPOLYGON`, with optional Z that is ignored): the stable
//! areas of a project.

/// A polygon with holes, in the project's horizontal coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Polygon {
    /// Outer ring, closed or not.
    pub exterior: Vec<[f64; 2]>,
    /// Inner rings.
    pub holes: Vec<Vec<[f64; 2]>>,
}

impl Polygon {
    /// Whether the point is inside the polygon (even–odd rule over all rings).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        std::iter::once(&self.exterior)
            .chain(&self.holes)
            .filter(|ring| ring_contains(ring, x, y))
            .count()
            % 2
            == 1
    }
}

/// Whether a point is inside one ring (even–odd crossing rule; the ring may be closed or not).
pub fn ring_contains(ring: &[[f64; 2]], x: f64, y: f64) -> bool {
    let mut inside = false;
    let n = ring.len();
    for i in 0..n {
        let [xi, yi] = ring[i];
        let [xj, yj] = ring[(i + n - 1) % n];
        if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
            inside = !inside;
        }
    }
    inside
}

/// Parses `POLYGON (...)` or `MULTIPOLYGON (...)` into polygons. The message of an error says what
/// was expected where.
pub fn parse_polygons(text: &str) -> Result<Vec<Polygon>, String> {
    let mut p = Parser {
        s: text.as_bytes(),
        i: 0,
    };
    let keyword = p.word().to_ascii_uppercase();
    let polygons = match keyword.as_str() {
        "POLYGON" => {
            p.optional_dimension();
            vec![p.polygon()?]
        }
        "MULTIPOLYGON" => {
            p.optional_dimension();
            p.expect(b'(')?;
            let mut polys = vec![p.polygon()?];
            while p.eat(b',') {
                polys.push(p.polygon()?);
            }
            p.expect(b')')?;
            polys
        }
        other => {
            return Err(format!(
                "expected POLYGON or MULTIPOLYGON, found \"{other}\""
            ));
        }
    };
    p.skip_ws();
    if p.i != p.s.len() {
        return Err(format!(
            "unexpected text after the geometry at character {}",
            p.i + 1
        ));
    }
    Ok(polygons)
}

struct Parser<'a> {
    s: &'a [u8],
    i: usize,
}

impl Parser<'_> {
    fn skip_ws(&mut self) {
        while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
            self.i += 1;
        }
    }
    fn word(&mut self) -> String {
        self.skip_ws();
        let start = self.i;
        while self.i < self.s.len() && self.s[self.i].is_ascii_alphabetic() {
            self.i += 1;
        }
        String::from_utf8_lossy(&self.s[start..self.i]).into_owned()
    }
    fn optional_dimension(&mut self) {
        let save = self.i;
        let w = self.word().to_ascii_uppercase();
        if !(w == "Z" || w == "M" || w == "ZM") {
            self.i = save;
        }
    }
    fn eat(&mut self, c: u8) -> bool {
        self.skip_ws();
        if self.s.get(self.i) == Some(&c) {
            self.i += 1;
            true
        } else {
            false
        }
    }
    fn expect(&mut self, c: u8) -> Result<(), String> {
        if self.eat(c) {
            Ok(())
        } else {
            Err(format!(
                "expected '{}' at character {}",
                c as char,
                self.i + 1
            ))
        }
    }
    fn number(&mut self) -> Result<f64, String> {
        self.skip_ws();
        let start = self.i;
        while self.i < self.s.len()
            && (self.s[self.i].is_ascii_digit() || b"+-.eE".contains(&self.s[self.i]))
        {
            self.i += 1;
        }
        let t = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("expected a number at character {}", start + 1))
    }
    fn ring(&mut self) -> Result<Vec<[f64; 2]>, String> {
        self.expect(b'(')?;
        let mut pts = Vec::new();
        loop {
            let x = self.number()?;
            let y = self.number()?;
            // Optional Z/M values are ignored.
            loop {
                self.skip_ws();
                match self.s.get(self.i) {
                    Some(b',') | Some(b')') | None => break,
                    _ => {
                        self.number()?;
                    }
                }
            }
            pts.push([x, y]);
            if !self.eat(b',') {
                break;
            }
        }
        self.expect(b')')?;
        if pts.len() < 3 {
            return Err(format!(
                "a ring needs at least 3 vertices, got {}",
                pts.len()
            ));
        }
        Ok(pts)
    }
    fn polygon(&mut self) -> Result<Polygon, String> {
        self.expect(b'(')?;
        let exterior = self.ring()?;
        let mut holes = Vec::new();
        while self.eat(b',') {
            holes.push(self.ring()?);
        }
        self.expect(b')')?;
        Ok(Polygon { exterior, holes })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polygon_with_hole_contains_points_correctly() {
        let p =
            parse_polygons("POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0), (4 4, 6 4, 6 6, 4 6, 4 4))")
                .unwrap();
        assert_eq!(p.len(), 1);
        assert!(p[0].contains(1.0, 1.0));
        assert!(!p[0].contains(5.0, 5.0));
        assert!(!p[0].contains(11.0, 5.0));
    }

    #[test]
    fn multipolygon_with_z_parses() {
        let p = parse_polygons(
            "MULTIPOLYGON Z (((0 0 1, 1 0 1, 1 1 1, 0 0 1)), ((5 5 0, 6 5 0, 6 6 0)))",
        )
        .unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(p[1].exterior[2], [6.0, 6.0]);
    }

    #[test]
    fn malformed_wkt_says_what_was_expected() {
        assert!(
            parse_polygons("LINESTRING (0 0, 1 1)")
                .unwrap_err()
                .contains("POLYGON")
        );
        assert!(
            parse_polygons("POLYGON ((0 0, 1 x, 1 1))")
                .unwrap_err()
                .contains("number")
        );
        assert!(
            parse_polygons("POLYGON ((0 0, 1 1))")
                .unwrap_err()
                .contains("3 vertices")
        );
        assert!(parse_polygons("POLYGON ((0 0, 1 0, 1 1)) junk").is_err());
    }
}
