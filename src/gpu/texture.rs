//! Textures packed for `shaders/trace.wgsl`: a texture use as one word, and every texture's
//! texels in one array, read as [`crate::texture::Texture::sample`] reads them.

use std::sync::Arc;

use crate::bvh::INVALID_INDEX;
use crate::texture::{TexelFormat, Texture, TextureRef, srgb_table};

/// [`TextureRef`] packed for the GPU: the texture's index in the low 24 bits, the wrap in the
/// next two, sRGB in bit 26; [`INVALID_INDEX`] for none.
pub fn gpu_texture_ref(r: Option<TextureRef>) -> u32 {
    r.map_or(INVALID_INDEX, |r| r.texture | (r.wrap as u32) << 24 | u32::from(r.srgb) << 26)
}

/// A texture's channel as the GPU reads it: [`gpu_texture_ref`] with the channel (0 to 3) in
/// bits 27 and 28, read as stored (no sRGB decoding), as [`RenderMaterial::bsdf_at`] reads it.
///
/// [`RenderMaterial::bsdf_at`]: crate::render::RenderMaterial::bsdf_at
pub fn gpu_texture_channel(r: Option<(TextureRef, u8)>) -> u32 {
    r.map_or(INVALID_INDEX, |(r, c)| gpu_texture_ref(Some(TextureRef { srgb: false, ..r })) | u32::from(c & 3) << 27)
}

/// Every texture as `shaders/trace.wgsl` reads them, one array of words: the 256 values of
/// [`crate::image_io::srgb_decode`] as f32 bits (so both devices decode alike), four header
/// words a texture (offset of its texels in the array, width, height, flags: bit 0 f32 texels,
/// bit 1 an alpha channel), then the texels.
pub fn gpu_texture_data(textures: &[Arc<Texture>]) -> Vec<u32> {
    let mut data =
        Vec::with_capacity(256 + 4 * textures.len() + textures.iter().map(|t| t.texels.len()).sum::<usize>());
    data.extend(srgb_table().iter().map(|c| c.to_bits()));
    let mut offset = 256 + 4 * textures.len() as u32;
    for t in textures {
        let flags = u32::from(t.format == TexelFormat::Rgba32F) | u32::from(t.has_alpha) << 1;
        data.extend([offset, t.width, t.height, flags]);
        offset += t.texels.len() as u32;
    }
    for t in textures {
        data.extend(&t.texels);
    }
    data
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::{Wrap, test_texture as rgba8};

    #[test]
    fn gpu_data_has_headers_then_texels() {
        let (a, b) = (Arc::new(rgba8(2, 1, |x, _| [x as u8, 0, 0, 0])), Arc::new(rgba8(1, 1, |_, _| [9, 0, 0, 0])));
        let data = gpu_texture_data(&[a, b]);
        assert_eq!(f32::from_bits(data[255]), 1.0);
        assert_eq!(&data[256..264], &[264, 2, 1, 2, 266, 1, 1, 2]);
        assert_eq!(data.len(), 267);
        let r = TextureRef { texture: 5, wrap: Wrap::Mirror, srgb: true };
        assert_eq!(gpu_texture_ref(Some(r)), 5 | 2 << 24 | 1 << 26);
    }
}
