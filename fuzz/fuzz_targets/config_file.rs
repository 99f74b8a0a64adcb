//! Config files on arbitrary UTF-8: alfd's (`Config::from_text`, which includes the
//! `[mavlink]` table `LinkConfig::from_toml` reads) and firmware-sim's
//! (`SimConfig::from_toml`). A config or a typed error, never a panic; the same text gives
//! the same config, and every error names the file (and an invalid value its field).
#![no_main]

use alfd::config::{Config, ConfigError};
use alfd::link::LinkConfig;
use firmware_sim::SimConfig;
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Config::from_text(text, "fuzz.toml") {
        // Parsing is a function of the text: the same text gives the same config.
        Ok(c) => {
            let again = Config::from_text(text, "fuzz.toml").expect("parsed once, parses again");
            assert_eq!(format!("{c:?}"), format!("{again:?}"));
            if let Some(why) = c.unsupported_by_build() {
                assert!(!why.is_empty());
            }
        }
        // Every error names the file, and an invalid value names its field.
        Err(e) => {
            assert!(e.to_string().starts_with("config fuzz.toml: "), "{e}");
            if let ConfigError::Invalid { field, message, .. } = &e {
                assert!(!field.is_empty() && !message.is_empty(), "{e}");
            }
        }
    }
    if let Err(e) = LinkConfig::from_toml(text) {
        assert!(!e.to_string().is_empty());
    }
    if let Err(e) = SimConfig::from_toml(text) {
        assert!(!e.to_string().is_empty());
    }
});
