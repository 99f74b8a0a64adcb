//! WGS-84 geodetic coordinates to local north-east-down metres around a home point and back.
//! The projection is the exact tangent plane through Earth-centred coordinates: horizontal
//! distances are geodesic ones shortened by the plane's own d³/6R² (0.3 mm at 4 km).

/// WGS-84 semi-major axis (m).
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS-84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// A geodetic position: latitude and longitude in degrees (the config and MAVLink edge), height in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geodetic {
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f64,
}

/// A local north-east-down frame with its origin at `home`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalFrame {
    home: Geodetic,
    origin_ecef_m: [f64; 3],
    /// Rows: the north, east and down unit vectors in Earth-centred coordinates.
    rot: [[f64; 3]; 3],
}

fn e2() -> f64 {
    WGS84_F * (2.0 - WGS84_F)
}

/// Geodetic to Earth-centred, Earth-fixed metres.
pub fn to_ecef(p: Geodetic) -> [f64; 3] {
    let (lat, lon) = (p.lat_deg.to_radians(), p.lon_deg.to_radians());
    let n = WGS84_A_M / (1.0 - e2() * lat.sin().powi(2)).sqrt();
    [
        (n + p.alt_m) * lat.cos() * lon.cos(),
        (n + p.alt_m) * lat.cos() * lon.sin(),
        (n * (1.0 - e2()) + p.alt_m) * lat.sin(),
    ]
}

/// Earth-centred metres to geodetic (fixed-point iteration on latitude; converges to 1e-12 rad
/// in a few steps anywhere a drone flies).
pub fn from_ecef(x: [f64; 3]) -> Geodetic {
    let p = x[0].hypot(x[1]);
    let lon = x[1].atan2(x[0]);
    let mut lat = x[2].atan2(p * (1.0 - e2()));
    let mut alt = 0.0;
    for _ in 0..8 {
        let n = WGS84_A_M / (1.0 - e2() * lat.sin().powi(2)).sqrt();
        alt = p / lat.cos() - n;
        lat = x[2].atan2(p * (1.0 - e2() * n / (n + alt)));
    }
    Geodetic {
        lat_deg: lat.to_degrees(),
        lon_deg: lon.to_degrees(),
        alt_m: alt,
    }
}

impl LocalFrame {
    pub fn new(home: Geodetic) -> Self {
        let (lat, lon) = (home.lat_deg.to_radians(), home.lon_deg.to_radians());
        let (sl, cl, so, co) = (lat.sin(), lat.cos(), lon.sin(), lon.cos());
        let north = [-sl * co, -sl * so, cl];
        let east = [-so, co, 0.0];
        let down = [-cl * co, -cl * so, -sl];
        Self {
            home,
            origin_ecef_m: to_ecef(home),
            rot: [north, east, down],
        }
    }

    pub fn home(&self) -> Geodetic {
        self.home
    }

    /// North, east, down metres of `p` from home.
    pub fn to_ned(&self, p: Geodetic) -> [f64; 3] {
        let x = to_ecef(p);
        let d = [
            x[0] - self.origin_ecef_m[0],
            x[1] - self.origin_ecef_m[1],
            x[2] - self.origin_ecef_m[2],
        ];
        self.rot.map(|r| r[0] * d[0] + r[1] * d[1] + r[2] * d[2])
    }

    /// The geodetic position `ned` metres from home.
    pub fn to_geodetic(&self, ned: [f64; 3]) -> Geodetic {
        let r = &self.rot;
        let mut x = self.origin_ecef_m;
        for (k, xk) in x.iter_mut().enumerate() {
            *xk += r[0][k] * ned[0] + r[1][k] * ned[1] + r[2][k] * ned[2];
        }
        from_ecef(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_is_exact_to_a_tenth_of_a_millimetre() {
        let f = LocalFrame::new(Geodetic {
            lat_deg: 47.4,
            lon_deg: 8.5,
            alt_m: 400.0,
        });
        for ned in [
            [0.0, 0.0, 0.0],
            [1500.0, -800.0, -120.0],
            [-3000.0, 2500.0, 30.0],
        ] {
            let back = f.to_ned(f.to_geodetic(ned));
            for (b, n) in back.iter().zip(ned) {
                assert!((b - n).abs() < 1e-4, "{ned:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn home_maps_to_origin() {
        let h = Geodetic {
            lat_deg: -33.9,
            lon_deg: 151.2,
            alt_m: 20.0,
        };
        let n = LocalFrame::new(h).to_ned(h);
        assert!(n.iter().all(|v| v.abs() < 1e-6));
    }
}
