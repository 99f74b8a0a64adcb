//! Which V4L2 device is ours: cameras re-enumerate (a USB reset turns
//! /dev/video2 into /dev/video4), so a device is named by what does not change
//! (its USB serial, its bus, its card name) and found again by scanning. The
//! matching is pure; the scan of /sys lives in the `v4l2` module.

use std::path::PathBuf;

/// What the config says about the device; unset fields match anything.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DeviceSelector {
    /// A fixed path (`/dev/video2`); when set, nothing else is consulted.
    pub path: Option<PathBuf>,
    /// USB serial number (e.g. a RealSense's, from sysfs).
    pub serial: Option<String>,
    /// V4L2 bus info (`usb-0000:01:00.0-1.2`).
    pub bus: Option<String>,
    /// Substring of the card name (`Intel(R) RealSense(TM) Depth Camera 435`).
    pub card: Option<String>,
}

/// One device node as found by a scan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    pub path: PathBuf,
    pub serial: Option<String>,
    pub bus: String,
    pub card: String,
    /// Pixel formats it can capture, as FourCC strings (`"Z16 "`, `"YUYV"`, `"MJPG"`).
    pub formats: Vec<String>,
}

impl DeviceSelector {
    pub fn matches(&self, d: &DeviceInfo, fourcc: &str) -> bool {
        if let Some(p) = &self.path {
            return *p == d.path;
        }
        self.serial
            .as_ref()
            .is_none_or(|s| d.serial.as_ref() == Some(s))
            && self.bus.as_ref().is_none_or(|b| *b == d.bus)
            && self
                .card
                .as_ref()
                .is_none_or(|c| d.card.contains(c.as_str()))
            && d.formats.iter().any(|f| f == fourcc)
    }

    /// The first device (by path) that matches and captures `fourcc`.
    pub fn pick<'a>(&self, devices: &'a [DeviceInfo], fourcc: &str) -> Option<&'a DeviceInfo> {
        let mut found: Vec<&DeviceInfo> =
            devices.iter().filter(|d| self.matches(d, fourcc)).collect();
        found.sort_by(|a, b| a.path.cmp(&b.path));
        found.first().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev(path: &str, serial: &str, bus: &str, formats: &[&str]) -> DeviceInfo {
        DeviceInfo {
            path: PathBuf::from(path),
            serial: Some(serial.into()),
            bus: bus.into(),
            card: "Intel(R) RealSense(TM) Depth Camera 435".into(),
            formats: formats.iter().map(|s| s.to_string()).collect(),
        }
    }

    #[test]
    fn a_camera_is_found_again_after_re_enumeration() {
        let sel = DeviceSelector {
            serial: Some("123456".into()),
            ..DeviceSelector::default()
        };
        let before = [
            dev("/dev/video0", "123456", "usb-1", &["Z16 "]),
            dev("/dev/video2", "123456", "usb-1", &["YUYV"]),
        ];
        assert_eq!(
            sel.pick(&before, "Z16 ").unwrap().path,
            PathBuf::from("/dev/video0")
        );
        assert_eq!(
            sel.pick(&before, "YUYV").unwrap().path,
            PathBuf::from("/dev/video2")
        );
        // After a USB reset the same camera comes back under new nodes.
        let after = [
            dev("/dev/video4", "123456", "usb-1", &["Z16 "]),
            dev("/dev/video6", "999", "usb-2", &["Z16 "]),
        ];
        assert_eq!(
            sel.pick(&after, "Z16 ").unwrap().path,
            PathBuf::from("/dev/video4")
        );
        // Another camera's serial never matches.
        let other = [dev("/dev/video0", "999", "usb-1", &["Z16 "])];
        assert!(sel.pick(&other, "Z16 ").is_none());
        let by_card = DeviceSelector {
            card: Some("RealSense".into()),
            ..DeviceSelector::default()
        };
        assert!(by_card.pick(&after, "Z16 ").is_some());
        assert!(by_card.pick(&after, "MJPG").is_none());
    }
}
