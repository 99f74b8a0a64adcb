//! Writes the depth maps shipped in `tests/data/` from the analytic box world
//! (`alfd::synth`), so anyone can regenerate and check them:
//! `cargo run --example make_test_maps -- tests/data`.

use alfd::core::{DepthData, Intrinsics};
use alfd::depthio::{encode_pfm, encode_png16, encode_z16};
use alfd::synth::{dropout, reference_scenes, to_z16};
use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "tests/data".into()),
    );
    std::fs::create_dir_all(&dir)?;
    let scenes = reference_scenes();
    let find = |name: &str| {
        scenes
            .iter()
            .find(|s| s.0 == name)
            .expect("scene exists")
            .clone()
    };

    // roof: nadir over a 20 m building from 40 m, two depth levels exactly (Z16, mm).
    let (_, world, pose) = find("roof");
    let intr = Intrinsics::from_hfov_deg(160, 120, 69.0, None)?;
    let z = to_z16(&world.render_depth(&pose, &intr), 0.001);
    std::fs::write(dir.join("roof_160x120.z16"), encode_z16(&z))?;

    // buildings: four buildings seen at 20° forward pitch (16-bit PNG, mm).
    let (_, world, pose) = find("buildings");
    let intr = Intrinsics::from_hfov_deg(320, 240, 69.0, None)?;
    let z = to_z16(&world.render_depth(&pose, &intr), 0.001);
    std::fs::write(
        dir.join("buildings_320x240.png"),
        encode_png16(320, 240, &z)?,
    )?;

    // street: 60° forward pitch, sky above the horizon, 10 % dropout (PFM, metres).
    let (_, world, pose) = find("street");
    let intr = Intrinsics::from_hfov_deg(64, 48, 90.0, None)?;
    let mut d = world.render_depth(&pose, &intr);
    dropout(&mut d, 0.1, 42);
    std::fs::write(dir.join("street_64x48.pfm"), encode_pfm(64, 48, &d))?;
    // Sanity: what was written decodes to what was rendered.
    let back = alfd::depthio::decode_pfm(&std::fs::read(dir.join("street_64x48.pfm"))?, None)?;
    let DepthData::Metres(b) = back.data() else {
        anyhow::bail!("PFM decoded to Z16")
    };
    // Bitwise, since NaN != NaN.
    assert!(b.iter().zip(&d).all(|(x, y)| x.to_bits() == y.to_bits()) && b.len() == d.len());
    println!(
        "wrote roof_160x120.z16, buildings_320x240.png, street_64x48.pfm to {}",
        dir.display()
    );
    Ok(())
}
