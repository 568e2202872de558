//! Writes the linker memory map for the bare-metal target only (the host build is a plain library).
use std::{env, fs, path::PathBuf};

/// mps2-an386 (QEMU): 4 MiB of code memory at 0, 4 MiB of RAM at 0x2000_0000. The top 64 KiB
/// of the code memory (0x003F_0000) is left out: it holds the calibration store.
const MEMORY_X: &str = "MEMORY\n{\n  FLASH : ORIGIN = 0x00000000, LENGTH = 4032K\n  RAM : ORIGIN = 0x20000000, LENGTH = 4M\n}\n";

/// STM32F429ZI: 2 MiB flash in two banks; sectors 10 and 11 (128 KiB each at 0x080C_0000) hold
/// the calibration store, so the program gets sectors 0-9 (768 KiB). RAM: the 192 KiB of
/// SRAM1-3, contiguous at 0x2000_0000 (the 64 KiB CCM is left unused).
const MEMORY_X_NUCLEO_F429ZI: &str = "MEMORY\n{\n  FLASH : ORIGIN = 0x08000000, LENGTH = 768K\n  RAM : ORIGIN = 0x20000000, LENGTH = 192K\n}\n";

fn main() {
    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
        let memory = if env::var_os("CARGO_FEATURE_NUCLEO_F429ZI").is_some() {
            MEMORY_X_NUCLEO_F429ZI
        } else {
            MEMORY_X
        };
        fs::write(out.join("memory.x"), memory).expect("write memory.x");
        println!("cargo:rustc-link-search={}", out.display());
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
