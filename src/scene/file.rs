//! The scene file as written: serde structs mirroring the TOML, every leaf `Spanned` so that
//! checks after parsing can still name the line. Unknown keys, arrays of the wrong length and
//! arrays where a table belongs are rejected here.

use std::collections::BTreeMap;
use std::fmt;
use std::marker::PhantomData;

use serde::Deserialize;
use serde::de::value::{MapAccessDeserializer, SeqAccessDeserializer};
use serde::de::{Deserializer, Error as _, MapAccess, SeqAccess, Visitor};
use toml::Spanned;

pub(super) type S<T> = Spanned<T>;
/// A 4x4 matrix as written, row by row.
pub(super) type Rows = [[f32; 4]; 4];
/// An array of tables (`[[objects.keyframes]]`), each with its span, and the array's.
pub(super) type TableList<T> = S<Vec<S<T>>>;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SceneFile {
    #[serde(deserialize_with = "table")]
    pub camera: S<CameraFile>,
    #[serde(default, deserialize_with = "table_opt")]
    pub render: Option<S<RenderFile>>,
    #[serde(default, deserialize_with = "table_opt")]
    pub environment: Option<S<EnvironmentFile>>,
    #[serde(default, deserialize_with = "tables_by_name")]
    pub materials: BTreeMap<String, S<MaterialFile>>,
    #[serde(default, deserialize_with = "table_list")]
    pub objects: Vec<S<ObjectFile>>,
    #[serde(default, deserialize_with = "table_opt")]
    pub animation: Option<S<AnimationFile>>,
}

/// `position`, `look_at` and `fov` are required unless `from` names a glTF file to take the
/// camera from (checked when building, at the table's line).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CameraFile {
    #[serde(default, deserialize_with = "exact_opt")]
    pub position: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub look_at: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub up: Option<S<[f32; 3]>>,
    pub fov: Option<S<f32>>,
    /// A glTF file (relative to the scene) whose camera node this is.
    pub from: Option<S<String>>,
    /// Which camera node of `from`: a node's or a camera's name.
    pub name: Option<S<String>>,
    #[serde(deserialize_with = "exact")]
    pub resolution: S<[u32; 2]>,
    pub aperture: Option<S<f32>>,
    pub focus_distance: Option<S<f32>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RenderFile {
    pub spp: Option<S<u32>>,
    pub max_depth: Option<S<u32>>,
    pub seed: Option<S<u64>>,
    pub time: Option<S<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct EnvironmentFile {
    #[serde(default, deserialize_with = "exact_opt")]
    pub radiance: Option<S<[f32; 3]>>,
    pub map: Option<S<String>>,
    pub scale: Option<S<ScaleFile>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub rotate: Option<S<[f32; 3]>>,
}

/// Every key any material type takes; which ones a type allows is checked when building.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MaterialFile {
    #[serde(rename = "type")]
    pub kind: S<String>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub albedo: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub radiance: Option<S<[f32; 3]>>,
    pub two_sided: Option<S<bool>>,
    pub roughness: Option<S<f32>>,
    pub metallic: Option<S<f32>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub eta: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub k: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub base_color: Option<S<[f32; 3]>>,
    pub ior: Option<S<f32>>,
    pub texture: Option<S<String>>,
    pub alpha_texture: Option<S<String>>,
    pub normal_texture: Option<S<String>>,
    pub emission_texture: Option<S<String>>,
    pub roughness_texture: Option<S<String>>,
    pub metallic_texture: Option<S<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ObjectFile {
    pub mesh: Option<S<String>>,
    pub shape: Option<S<String>>,
    pub subdivisions: Option<S<u32>>,
    pub triangles: Option<S<u64>>,
    pub seed: Option<S<u64>>,
    pub material: Option<S<String>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub translate: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub rotate: Option<S<[f32; 3]>>,
    pub scale: Option<S<ScaleFile>>,
    #[serde(default, deserialize_with = "exact_matrix")]
    pub matrix: Option<S<Rows>>,
    #[serde(default, deserialize_with = "table_list_opt")]
    pub keyframes: Option<TableList<KeyframeFile>>,
    #[serde(default, deserialize_with = "table_opt")]
    pub scatter: Option<S<ScatterFile>>,
}

pub(super) enum ScaleFile {
    Uniform(f32),
    PerAxis([f32; 3]),
}

/// By hand rather than `untagged`, whose error names no length or type.
impl<'de> Deserialize<'de> for ScaleFile {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Scale;
        impl<'de> Visitor<'de> for Scale {
            type Value = ScaleFile;

            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or an array of 3 numbers")
            }

            fn visit_f64<E: serde::de::Error>(self, x: f64) -> Result<ScaleFile, E> {
                Ok(ScaleFile::Uniform(x as f32))
            }

            fn visit_i64<E: serde::de::Error>(self, x: i64) -> Result<ScaleFile, E> {
                Ok(ScaleFile::Uniform(x as f32))
            }

            fn visit_u64<E: serde::de::Error>(self, x: u64) -> Result<ScaleFile, E> {
                Ok(ScaleFile::Uniform(x as f32))
            }

            fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<ScaleFile, A::Error> {
                Exact::<f32, 3>::deserialize(SeqAccessDeserializer::new(seq)).map(|a| ScaleFile::PerAxis(a.0))
            }
        }
        d.deserialize_any(Scale)
    }
}

/// Required keys are `Option` here so that a missing one is reported at its table's line.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AnimationFile {
    pub fps: Option<S<f32>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub frames: Option<S<[u32; 2]>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct KeyframeFile {
    pub time: Option<S<f32>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub translate: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub rotate: Option<S<[f32; 3]>>,
    pub scale: Option<S<ScaleFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ScatterFile {
    pub count: Option<S<u64>>,
    pub seed: Option<S<u64>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub min: Option<S<[f32; 3]>>,
    #[serde(default, deserialize_with = "exact_opt")]
    pub max: Option<S<[f32; 3]>>,
    pub moving: Option<S<f32>>,
    pub radius: Option<S<f32>>,
    pub period: Option<S<f32>>,
}

/// An array of exactly `N` elements. serde's `[T; N]` reads the first `N` elements of a longer
/// array, and toml lets the rest pass unread: `resolution = [16, 16, 16]` would load.
struct Exact<T, const N: usize>([T; N]);

impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for Exact<T, N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = Vec::<T>::deserialize(d)?;
        let n = v.len();
        let expected = format!("an array of length {N}");
        v.try_into().map(Exact).map_err(|_| D::Error::invalid_length(n, &expected.as_str()))
    }
}

fn exact<'de, D: Deserializer<'de>, T: Deserialize<'de>, const N: usize>(d: D) -> Result<S<[T; N]>, D::Error> {
    let s = S::<Exact<T, N>>::deserialize(d)?;
    Ok(S::new(s.span(), s.into_inner().0))
}

fn exact_opt<'de, D: Deserializer<'de>, T: Deserialize<'de>, const N: usize>(
    d: D,
) -> Result<Option<S<[T; N]>>, D::Error> {
    exact(d).map(Some)
}

/// A 4x4 matrix, row by row: 4 arrays of 4 numbers.
fn exact_matrix<'de, D: Deserializer<'de>>(d: D) -> Result<Option<S<Rows>>, D::Error> {
    let s = S::<Exact<Exact<f32, 4>, 4>>::deserialize(d)?;
    Ok(Some(S::new(s.span(), s.into_inner().0.map(|row| row.0))))
}

/// A struct read from a TOML table only. serde's derive also reads a struct from an array, field
/// by field, which turned `[[camera]]` into "camera[0]: invalid type: map, expected a
/// sequence".
struct Table<T>(T);

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Table<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Only<T>(PhantomData<T>);
        impl<'de, T: Deserialize<'de>> Visitor<'de> for Only<T> {
            type Value = T;

            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a table")
            }

            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<T, A::Error> {
                T::deserialize(MapAccessDeserializer::new(map))
            }
        }
        d.deserialize_any(Only(PhantomData)).map(Table)
    }
}

fn untable<T>(s: S<Table<T>>) -> S<T> {
    S::new(s.span(), s.into_inner().0)
}

fn table<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<S<T>, D::Error> {
    S::<Table<T>>::deserialize(d).map(untable)
}

fn table_opt<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<Option<S<T>>, D::Error> {
    table(d).map(Some)
}

fn tables_by_name<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<BTreeMap<String, S<T>>, D::Error> {
    Ok(BTreeMap::<String, S<Table<T>>>::deserialize(d)?.into_iter().map(|(k, v)| (k, untable(v))).collect())
}

fn table_list<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<Vec<S<T>>, D::Error> {
    Ok(Vec::<S<Table<T>>>::deserialize(d)?.into_iter().map(untable).collect())
}

fn table_list_opt<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<Option<TableList<T>>, D::Error> {
    let s = S::<Vec<S<Table<T>>>>::deserialize(d)?;
    Ok(Some(S::new(s.span(), s.into_inner().into_iter().map(untable).collect())))
}
