//! The capture log of one flight: images, `manifest.jsonl` and the exports
//! (`geo.txt`, `transforms.json`, EXIF GPS, `telemetry.tlog`), and an external
//! camera's pictures paired with its captures ([`external`]). Records and encoders
//! are pure; [`store`] is the only part that writes files. Schema and guarantees:
//! docs/capture-log.md.

pub mod exif;
pub mod export;
pub mod external;
pub mod jpeg;
pub mod record;
pub mod store;
pub mod tlog;

pub use exif::{
    encode_capture, encode_jpeg, encode_png, exif_app1, find_exif_app1, parse_exif_gps, ExifGps,
    ImageError,
};
pub use export::{
    camera_to_world_gl, export_flight, export_flight_with_camera, geo_txt, transforms,
    write_exports, ExportError, ExportSummary, FlightExport,
};
pub use record::{
    image_file_name, Attitude, CameraIntrinsics, CaptureMode, CaptureRecord, ClosedLoopRecord,
    ImageFormat, Occlusion, Position, QualityRecord, QualitySpacingM, QualityTargets,
    QualityValues, Spacing,
};
pub use store::{
    log_capture, parse_manifest, read_manifest, CaptureStore, DirStore, FillingStore, LogError,
    Manifest, MemStore, StoreError, MANIFEST, TELEMETRY,
};
pub use tlog::{TlogEntry, TlogWriter};
