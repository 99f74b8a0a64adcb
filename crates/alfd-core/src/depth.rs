//! Depth images and camera intrinsics as the core sees them: validated once at
//! construction, so every later stage may rely on `width·height == data.len()`,
//! a finite positive focal length and a field of view inside the supported range.

use thiserror::Error;

/// Supported horizontal field of view, degrees (inclusive).
pub const HFOV_MIN_DEG: f64 = 1.0;
pub const HFOV_MAX_DEG: f64 = 170.0;

/// Pixel values of one depth frame, row-major, `width` pixels per row.
#[derive(Debug, Clone, PartialEq)]
pub enum DepthData {
    /// RealSense-style Z16: depth along the optical axis in units of `scale_m`;
    /// 0 means no return and `u16::MAX` a saturated pixel, both invalid.
    Z16 { data: Vec<u16>, scale_m: f64 },
    /// Depth along the optical axis in metres: `+inf` is sky, NaN or `<= 0` invalid.
    Metres(Vec<f32>),
}

impl DepthData {
    pub fn len(&self) -> usize {
        match self {
            DepthData::Z16 { data, .. } => data.len(),
            DepthData::Metres(d) => d.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A depth frame whose size matches its data.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    width: usize,
    height: usize,
    data: DepthData,
}

#[derive(Debug, Error, Clone, PartialEq)]
pub enum DepthError {
    #[error("depth image is empty ({width}x{height}); it needs at least 1x1 pixels")]
    Empty { width: usize, height: usize },
    #[error("depth image is {width}x{height} = {expected} pixels but holds {found} values")]
    SizeMismatch {
        width: usize,
        height: usize,
        expected: usize,
        found: usize,
    },
    #[error("Z16 depth scale must be a finite positive number of metres, got {0}")]
    BadScale(f64),
}

impl DepthImage {
    pub fn new(width: usize, height: usize, data: DepthData) -> Result<Self, DepthError> {
        if width == 0 || height == 0 {
            return Err(DepthError::Empty { width, height });
        }
        let expected = width
            .checked_mul(height)
            .ok_or(DepthError::Empty { width, height })?;
        if data.len() != expected {
            return Err(DepthError::SizeMismatch {
                width,
                height,
                expected,
                found: data.len(),
            });
        }
        if let DepthData::Z16 { scale_m, .. } = &data {
            if !(scale_m.is_finite() && *scale_m > 0.0) {
                return Err(DepthError::BadScale(*scale_m));
            }
        }
        Ok(DepthImage {
            width,
            height,
            data,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn data(&self) -> &DepthData {
        &self.data
    }
    pub fn pixel_count(&self) -> usize {
        self.width * self.height
    }
}

/// Which image axis runs along the flight track (DESIGN §1: the estimator scans
/// lines in the flight direction, the epipolar direction for a translating camera).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TrackAxis {
    /// Image rows run along track: `u` (columns index) grows forward.
    #[default]
    Rows,
    /// Image columns run along track: `v` grows forward.
    Columns,
}

/// Pinhole intrinsics in pixels. The principal point is in continuous pixel
/// coordinates (pixel `u` has its centre at `u + 0.5`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    width: usize,
    height: usize,
    focal_px: f64,
    cx_px: f64,
    cy_px: f64,
}

#[derive(Debug, Error, Clone, PartialEq)]
pub enum IntrinsicsError {
    #[error("image size {width}x{height} must be at least 1x1")]
    EmptyImage { width: usize, height: usize },
    #[error(
        "horizontal field of view {0} deg is out of range: it must be between {HFOV_MIN_DEG} and {HFOV_MAX_DEG} degrees"
    )]
    FovOutOfRange(f64),
    #[error("focal length {0} px must be finite and positive")]
    BadFocal(f64),
    #[error("principal point ({0}, {1}) px must be finite")]
    BadPrincipalPoint(f64, f64),
}

impl Intrinsics {
    /// Intrinsics from the horizontal field of view (degrees) across `width`.
    pub fn from_hfov_deg(
        width: usize,
        height: usize,
        hfov_deg: f64,
        principal_px: Option<(f64, f64)>,
    ) -> Result<Self, IntrinsicsError> {
        if !(hfov_deg.is_finite() && (HFOV_MIN_DEG..=HFOV_MAX_DEG).contains(&hfov_deg)) {
            return Err(IntrinsicsError::FovOutOfRange(hfov_deg));
        }
        if width == 0 || height == 0 {
            return Err(IntrinsicsError::EmptyImage { width, height });
        }
        let focal_px = (width as f64 / 2.0) / (hfov_deg.to_radians() / 2.0).tan();
        Self::from_focal_px(width, height, focal_px, principal_px)
    }

    /// Intrinsics from a focal length in pixels.
    pub fn from_focal_px(
        width: usize,
        height: usize,
        focal_px: f64,
        principal_px: Option<(f64, f64)>,
    ) -> Result<Self, IntrinsicsError> {
        if width == 0 || height == 0 {
            return Err(IntrinsicsError::EmptyImage { width, height });
        }
        if !(focal_px.is_finite() && focal_px > 0.0) {
            return Err(IntrinsicsError::BadFocal(focal_px));
        }
        let (cx_px, cy_px) = principal_px.unwrap_or((width as f64 / 2.0, height as f64 / 2.0));
        if !(cx_px.is_finite() && cy_px.is_finite()) {
            return Err(IntrinsicsError::BadPrincipalPoint(cx_px, cy_px));
        }
        Ok(Intrinsics {
            width,
            height,
            focal_px,
            cx_px,
            cy_px,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn focal_px(&self) -> f64 {
        self.focal_px
    }
    pub fn principal_px(&self) -> (f64, f64) {
        (self.cx_px, self.cy_px)
    }

    /// Along-track geometry for the given track axis.
    pub fn track(&self, axis: TrackAxis) -> TrackGeometry {
        let (extent, c_along, across_extent, c_across) = match axis {
            TrackAxis::Rows => (self.width, self.cx_px, self.height, self.cy_px),
            TrackAxis::Columns => (self.height, self.cy_px, self.width, self.cx_px),
        };
        TrackGeometry {
            focal_px: self.focal_px,
            along_px: extent,
            c_along_px: c_along,
            across_px: across_extent,
            c_across_px: c_across,
            half_extent_px: extent as f64 / 2.0,
        }
    }
}

/// Intrinsics seen along the track: the `v` axis of the paper's 2-D slice.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackGeometry {
    pub focal_px: f64,
    /// Image extent along track, pixels.
    pub along_px: usize,
    pub c_along_px: f64,
    pub across_px: usize,
    pub c_across_px: f64,
    /// `v_m`: half the image extent along track (DESIGN §1), pixels.
    pub half_extent_px: f64,
}

impl TrackGeometry {
    /// Along-track image coordinate of pixel index `i` (its centre), from the principal point.
    #[inline]
    pub fn v_px(&self, i: usize) -> f64 {
        i as f64 + 0.5 - self.c_along_px
    }
    #[inline]
    pub fn across_px(&self, i: usize) -> f64 {
        i as f64 + 0.5 - self.c_across_px
    }
    /// `cos φ − t·sin φ` (`t = v/f`): the downward component of the ray through along-track
    /// pixel `i`, per unit along the optical axis, for a camera tilted `φ` forward from
    /// nadir (`sin_p`, `cos_p`). Above [`HORIZON_EPS`] the ray looks below the horizon.
    #[inline]
    pub fn ray_down(&self, i: usize, sin_p: f64, cos_p: f64) -> f64 {
        cos_p - self.v_px(i) / self.focal_px * sin_p
    }
}

/// `|cos φ − t·sin φ|` below which a ray is taken as lying on the camera's horizon:
/// neither below nor above it.
pub const HORIZON_EPS: f64 = 1e-9;
