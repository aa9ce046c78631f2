//! A build without the Cargo feature `gltf` has no glTF reader: a scene naming a glTF file (an
//! object's `mesh`, the camera's `from`) is refused at that key, with an error that says which
//! feature reads it, rather than read as an OBJ file or left to fail as an unknown format.

use std::path::Path;

use glam::Vec3;

use super::Ctx;
use super::objects::{Built, Parts};
use crate::scene::SceneError;
use crate::scene::file::{S, SceneFile};

/// The glTF files read so far: none, in a build that reads none. (A field, so that `parse`
/// makes it with `default()` in either build, which clippy refuses for a unit struct.)
#[derive(Default)]
pub(super) struct GltfFiles(());

/// The refusal of `file` at `key`.
fn no_gltf(ctx: &Ctx, file: &S<String>, key: &str) -> SceneError {
    let message = format!(
        "{}: this build of Arbor has no glTF support; the Cargo feature `gltf` (a default feature) brings it",
        file.get_ref()
    );
    ctx.err(file.span(), key, message)
}

/// An object naming a glTF file: refused.
pub(super) fn gltf_parts(
    ctx: &Ctx,
    key: &str,
    rel: &S<String>,
    _base: &Path,
    _out: &mut Built,
) -> Result<Parts, SceneError> {
    Err(no_gltf(ctx, rel, key))
}

/// A camera from a glTF file: refused.
pub(super) fn file_camera(
    ctx: &Ctx,
    _f: &SceneFile,
    from: &S<String>,
    _base: &Path,
    _gltf: &mut GltfFiles,
) -> Result<(Vec3, Vec3, Vec3, f32), SceneError> {
    Err(no_gltf(ctx, from, "camera.from"))
}

#[cfg(test)]
mod tests {
    use crate::scene::Scene;

    const CAMERA: &str = "[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\nfov = 40\nresolution = [8, 8]\n";

    /// The error `text`, read as `dir/s.toml`, gives.
    fn error(text: &str) -> String {
        Scene::parse(text, "dir/s.toml").map(|_| ()).expect_err("a glTF file in a build without glTF").to_string()
    }

    #[test]
    fn a_gltf_mesh_is_refused_with_the_feature_that_reads_it() {
        let text = format!(
            "{CAMERA}\n[[objects]]\nmaterial = \"m\"\nmesh = \"models/car.GLB\"\n\n[materials.m]\ntype = \"diffuse\"\nalbedo = [1, 1, 1]\n"
        );
        assert_eq!(
            error(&text),
            "dir/s.toml:9: objects[0].mesh: models/car.GLB: this build of Arbor has no glTF support; the Cargo \
             feature `gltf` (a default feature) brings it"
        );
        let text = format!("{CAMERA}\n[[objects]]\nmesh = \"car.gltf\"\n");
        assert!(error(&text).starts_with("dir/s.toml:8: objects[0].mesh: car.gltf: this build of Arbor has no glTF"));
    }

    #[test]
    fn a_camera_from_a_gltf_file_is_refused_with_the_feature_that_reads_it() {
        let text = "[camera]\nfrom = \"street.glb\"\nresolution = [8, 8]\n";
        assert_eq!(
            error(text),
            "dir/s.toml:2: camera.from: street.glb: this build of Arbor has no glTF support; the Cargo feature \
             `gltf` (a default feature) brings it"
        );
    }
}
