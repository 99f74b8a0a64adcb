//! Local NED metres around the survey origin to WGS-84 latitude, longitude and height, through
//! Earth-centred coordinates (the exact tangent plane; no flat-earth approximation).

const A: f64 = 6_378_137.0;
const F: f64 = 1.0 / 298.257_223_563;

fn e2() -> f64 {
    F * (2.0 - F)
}

/// Latitude (deg), longitude (deg) and height (m) of the point `ned` metres from `origin`.
pub fn ned_to_geodetic(origin: [f64; 3], ned: [f64; 3]) -> [f64; 3] {
    let (lat, lon) = (origin[0].to_radians(), origin[1].to_radians());
    let n0 = A / (1.0 - e2() * lat.sin().powi(2)).sqrt();
    let o = [
        (n0 + origin[2]) * lat.cos() * lon.cos(),
        (n0 + origin[2]) * lat.cos() * lon.sin(),
        (n0 * (1.0 - e2()) + origin[2]) * lat.sin(),
    ];
    let (sl, cl, so, co) = (lat.sin(), lat.cos(), lon.sin(), lon.cos());
    let (nv, ev, dv) = (
        [-sl * co, -sl * so, cl],
        [-so, co, 0.0],
        [-cl * co, -cl * so, -sl],
    );
    let x: Vec<f64> = (0..3)
        .map(|k| o[k] + nv[k] * ned[0] + ev[k] * ned[1] + dv[k] * ned[2])
        .collect();
    let p = x[0].hypot(x[1]);
    let mut la = x[2].atan2(p * (1.0 - e2()));
    let mut h = 0.0;
    for _ in 0..8 {
        let n = A / (1.0 - e2() * la.sin().powi(2)).sqrt();
        h = p / la.cos() - n;
        la = x[2].atan2(p * (1.0 - e2() * n / (n + h)));
    }
    [la.to_degrees(), x[1].atan2(x[0]).to_degrees(), h]
}
