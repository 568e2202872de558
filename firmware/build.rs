//! Writes the linker memory map for the bare-metal target only (the host build is a plain library).
use std::{env, fs, path::PathBuf};

/// mps2-an386 (QEMU): 4 MiB of code memory at 0, 4 MiB of RAM at 0x2000_0000. The top 64 KiB
/// of the code memory (0x003F_0000) is left out: it holds the calibration store.
const MEMORY_X: &str = "MEMORY\n{\n  FLASH : ORIGIN = 0x00000000, LENGTH = 4032K\n  RAM : ORIGIN = 0x20000000, LENGTH = 4M\n}\n";

/// STM32F401RE: 512 KiB flash; the program gets sectors 0-3 (16 KiB each: 64 KiB), sectors 4
/// (64 KiB) and 5 (128 KiB) hold the calibration store. RAM: 96 KiB at 0x2000_0000.
const MEMORY_X_NUCLEO_F401RE: &str = "MEMORY\n{\n  FLASH : ORIGIN = 0x08000000, LENGTH = 64K\n  RAM : ORIGIN = 0x20000000, LENGTH = 96K\n}\n";

fn main() {
    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
        let memory = if env::var_os("CARGO_FEATURE_NUCLEO_F401RE").is_some() {
            MEMORY_X_NUCLEO_F401RE
        } else {
            MEMORY_X
        };
        fs::write(out.join("memory.x"), memory).expect("write memory.x");
        println!("cargo:rustc-link-search={}", out.display());
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
