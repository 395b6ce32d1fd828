//! Lets this crate's tests find `libmujoco.so` without `LD_LIBRARY_PATH`: an rpath to the
//! directory that `sim/fetch-mujoco.sh` printed as `MUJOCO_DYNAMIC_LINK_DIR`.
fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
