//! Config files on arbitrary UTF-8: alfd's (`Config::from_text`, which includes the
//! `[mavlink]` table `LinkConfig::from_toml` reads) and firmware-sim's
//! (`SimConfig::from_toml`). A config or a typed error, never a panic.
#![no_main]

use alfd::config::Config;
use alfd::link::LinkConfig;
use firmware_sim::SimConfig;
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Config::from_text(text, "fuzz.toml") {
        Ok(c) => {
            let _ = c.unsupported_by_build();
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
    if let Err(e) = LinkConfig::from_toml(text) {
        let _ = e.to_string();
    }
    if let Err(e) = SimConfig::from_toml(text) {
        let _ = e.to_string();
    }
});
