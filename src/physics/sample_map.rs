//! The sample as a map: a base material plus inclusions (discs and rectangles), each with
//! its own elastic constants and surface height. Pure geometry; the raster and the physics
//! that use it live elsewhere.

use super::contact::Elastic;

/// The outline of an inclusion in sample coordinates (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outline {
    /// A disc: centre and radius (m).
    Disc { x: f64, y: f64, radius: f64 },
    /// A rectangle with sides along the axes: centre and half extents (m).
    Rectangle {
        x: f64,
        y: f64,
        half_width: f64,
        half_length: f64,
    },
}

impl Outline {
    /// Whether the point (x, y) (m) lies inside or on the boundary.
    pub fn contains(&self, px: f64, py: f64) -> bool {
        match *self {
            Outline::Disc { x, y, radius } => {
                let (dx, dy) = (px - x, py - y);
                dx * dx + dy * dy <= radius * radius
            }
            Outline::Rectangle {
                x,
                y,
                half_width,
                half_length,
            } => (px - x).abs() <= half_width && (py - y).abs() <= half_length,
        }
    }
}

/// One region of the sample: a material at a surface height.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    /// Elastic constants of the material.
    pub material: Elastic,
    /// Height of the region's surface above the base material's (m).
    pub height: f64,
}

/// A base material and inclusions on it; where inclusions overlap, the later one is on top.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleMap {
    /// Region 0 is the base; region i ≥ 1 is inclusion i − 1 of `outlines`.
    regions: Vec<Region>,
    outlines: Vec<Outline>,
}

impl SampleMap {
    /// A map of the base material alone, height 0.
    pub fn uniform(base: Elastic) -> Self {
        Self {
            regions: vec![Region {
                material: base,
                height: 0.0,
            }],
            outlines: Vec::new(),
        }
    }

    /// Adds an inclusion on top of everything so far; returns its region index.
    pub fn add(&mut self, outline: Outline, region: Region) -> usize {
        self.outlines.push(outline);
        self.regions.push(region);
        self.regions.len() - 1
    }

    /// Every region: the base first, then the inclusions in order.
    pub fn regions(&self) -> &[Region] {
        &self.regions
    }

    /// The region under the point (x, y) (m): the topmost inclusion containing it, else the
    /// base (0). Allocation-free: called on the real-time thread once per drive period.
    pub fn region_at(&self, x: f64, y: f64) -> usize {
        self.outlines
            .iter()
            .rposition(|o| o.contains(x, y))
            .map_or(0, |i| i + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn elastic(e: f64) -> Elastic {
        Elastic {
            youngs_modulus: e,
            poisson: 0.28,
        }
    }

    fn region(e: f64, height: f64) -> Region {
        Region {
            material: elastic(e),
            height,
        }
    }

    #[test]
    fn discs_and_rectangles_contain_their_points_and_no_others() {
        let disc = Outline::Disc {
            x: 1e-7,
            y: -2e-7,
            radius: 5e-8,
        };
        assert!(disc.contains(1e-7, -2e-7));
        assert!(disc.contains(1e-7 + 4.9e-8, -2e-7));
        assert!(!disc.contains(1e-7 + 3.6e-8, -2e-7 + 3.6e-8)); // |d| = 50.9 nm
        assert!(disc.contains(1e-7 + 3.5e-8, -2e-7 + 3.5e-8)); // |d| = 49.5 nm
        let rect = Outline::Rectangle {
            x: 0.0,
            y: 0.0,
            half_width: 2e-7,
            half_length: 1e-7,
        };
        assert!(rect.contains(1.99e-7, 0.99e-7));
        assert!(!rect.contains(2.01e-7, 0.0));
        assert!(!rect.contains(0.0, 1.01e-7));
        assert!(rect.contains(-1.99e-7, -0.99e-7));
    }

    #[test]
    fn later_inclusions_lie_on_top_and_the_base_is_everywhere_else() {
        let mut map = SampleMap::uniform(elastic(129e9));
        let big = map.add(
            Outline::Rectangle {
                x: 0.0,
                y: 0.0,
                half_width: 3e-7,
                half_length: 3e-7,
            },
            region(116.1e9, 0.0),
        );
        let small = map.add(
            Outline::Disc {
                x: 1e-7,
                y: 0.0,
                radius: 5e-8,
            },
            region(50e9, 2e-9),
        );
        assert_eq!((big, small), (1, 2));
        assert_eq!(map.region_at(0.0, 0.0), 1);
        assert_eq!(map.region_at(1e-7, 0.0), 2);
        assert_eq!(map.region_at(4e-7, 0.0), 0);
        assert_eq!(map.regions()[map.region_at(1e-7, 1e-8)].height, 2e-9);
        assert_eq!(
            map.regions()[map.region_at(-5e-7, 5e-7)].material,
            elastic(129e9)
        );
    }
}
