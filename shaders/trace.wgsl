// The path tracer's megakernel: one thread per pixel, looping over the pass's samples. The same
// integrator as src/render/integrator.rs (RenderScene::radiance and direct_light), with the
// traversal of src/bvh/trace/mod.rs over the leaf-collapsed tree (triangles in leaf order, as in
// MeshBvh), the watertight test of src/geometry/triangle.rs with its conservative t, and the
// error-bound ray offsets of src/geometry/ray.rs. Concatenated after bsdf.wgsl (src/gpu/trace.rs); the HAS_* constants choose what
// this variant compiles.

@group(0) @binding(0) var<storage, read> params: TraceParams;
// Binding 1, the tree's nodes, is declared by the form's traversal (bvh_binary.wgsl or
// bvh_wide8.wgsl).
@group(0) @binding(2) var<storage, read> triangles: array<GpuTriangle>;
@group(0) @binding(3) var<storage, read> materials: array<GpuMaterial>;
@group(0) @binding(4) var<storage, read> lights: array<GpuLight>;
@group(0) @binding(5) var<storage, read_write> film: array<GpuPixel>;
// Each triangle's vertex normals, nine floats in leaf order (HAS_SHADING_NORMALS).
@group(0) @binding(6) var<storage, read> normals: array<f32>;
// The environment map (HAS_ENV_MAP), src/gpu/trace.rs's env_map_data: RGB texels, then the
// sampling density per cell, the marginal CDF and the cell rows' conditional CDFs.
@group(0) @binding(7) var<storage, read> env_map: array<f32>;
// Textures (HAS_TEXTURES), src/gpu/texture.rs's gpu_texture_data: the sRGB decoding table,
// four header words a texture, the texels; and each triangle's texture coordinates, six floats
// in leaf order.
@group(0) @binding(8) var<storage, read> textures: array<u32>;
@group(0) @binding(9) var<storage, read> uvs: array<f32>;
// The primitive id of each triangle position: ties between hits at one distance go to the
// lowest, as on the CPU, in every tree form.
@group(0) @binding(10) var<storage, read> prim_ids: array<u32>;
// Two levels (HAS_INSTANCES; src/gpu/trace.rs's upload of an instanced scene): binding 1 holds
// the top-level tree over the instances (root at node 0, in the form traced; its leaves name
// instance positions) and then the meshes' trees, each from its own root; binding 2 the meshes'
// object-space triangles (with their normals and texture coordinates), each mesh's from its own
// base. Then the instances by position in the top level's leaf order, and each light id's area
// density (Lights::pdf_area; a light id is its instance's light_base plus the triangle's id in
// its mesh).
@group(0) @binding(13) var<storage, read> instances: array<GpuInstance>;
@group(0) @binding(14) var<storage, read> light_pdfs: array<f32>;

// The largest finite f32: "no hit yet". (Infinite literals are not valid WGSL.)
const T_FAR: f32 = 3.40282347e38;

// ---- random numbers ----

// PCG with 32 bits of state and the RXS-M-XS output (O'Neill 2014, section 6.3.4), one stream
// per (seed, pixel, sample): the state and the (odd) increment are hashes of the triple.
struct Rng {
    state: u32,
    inc: u32,
}

// A bijective 32-bit mix (Wellons' lowbias32).
fn mix32(x_in: u32) -> u32 {
    var x = x_in;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

fn rng_next(rng: ptr<function, Rng>) -> u32 {
    let old = (*rng).state;
    (*rng).state = old * 747796405u + (*rng).inc;
    let word = ((old >> ((old >> 28u) + 4u)) ^ old) * 277803737u;
    return (word >> 22u) ^ word;
}

fn rng_for_sample(pixel: u32, sample: u32) -> Rng {
    let h = mix32(mix32(mix32(params.seed_lo ^ 0x61726270u) ^ params.seed_hi) + pixel);
    let state = mix32(h ^ mix32(sample + 0x9e3779b9u));
    var rng = Rng(state, (mix32(state ^ 0x85ebca6bu) << 1u) | 1u);
    _ = rng_next(&rng);
    return rng;
}

// Uniform in [0, 1): 24 random bits, as the CPU's Rng::next_f32.
fn rng_f32(rng: ptr<function, Rng>) -> f32 {
    return f32(rng_next(rng) >> 8u) * (1.0 / 16777216.0);
}

fn rng_vec2(rng: ptr<function, Rng>) -> vec2<f32> {
    let x = rng_f32(rng);
    let y = rng_f32(rng);
    return vec2<f32>(x, y);
}

// ---- rays ----

struct Ray {
    origin: vec3<f32>,
    dir: vec3<f32>,
}

// CameraModel::ray.
fn camera_ray(film_pos: vec2<f32>, lens: vec2<f32>) -> Ray {
    let sx = (2.0 * film_pos.x / f32(params.width) - 1.0) * params.tan_x;
    let sy = (1.0 - 2.0 * film_pos.y / f32(params.height)) * params.tan_y;
    let dir = normalize_glam(params.cam_forward + params.cam_right * sx + params.cam_up * sy);
    if !HAS_THIN_LENS || params.lens_radius == 0.0 {
        return Ray(params.cam_origin, dir);
    }
    let focus = params.cam_origin + dir * (params.focus_distance / dot(dir, params.cam_forward));
    let d = concentric_disk(lens) * params.lens_radius;
    let origin = params.cam_origin + params.cam_right * d.x + params.cam_up * d.y;
    return Ray(origin, normalize_glam(focus - origin));
}

// A point on a surface and a bound on its rounding error per axis.
struct SurfacePoint {
    p: vec3<f32>,
    error: vec3<f32>,
}

// Triangle::point_with_error: v0 + u (v1 - v0) + v (v2 - v0), error at most
// γ₂ |p| + γ₄ (|u e1| + |v e2|).
fn point_with_error(v0: vec3<f32>, v1: vec3<f32>, v2: vec3<f32>, u: f32, v: f32) -> SurfacePoint {
    let ue1 = (v1 - v0) * u;
    let ve2 = (v2 - v0) * v;
    let p = v0 + (ue1 + ve2);
    return SurfacePoint(p, abs(p) * GAMMA2 + (abs(ue1) + abs(ve2)) * GAMMA4);
}

// The next f32 towards +inf (ray.rs's next_up; NaN and +inf stay).
fn next_up(v: f32) -> f32 {
    let bits = bitcast<u32>(v);
    let magnitude = bits & 0x7fffffffu;
    if magnitude >= 0x7f800000u && bits != 0xff800000u {
        return v; // NaN or +inf
    }
    if magnitude == 0u {
        return bitcast<f32>(1u);
    }
    return bitcast<f32>(select(bits - 1u, bits + 1u, (bits & 0x80000000u) == 0u));
}

// offset_ray_origin (pbrt-v4): off the surface along n (facing the side the ray leaves into) by
// the error box's extent along n, then one more float away on each axis that moved.
fn offset_ray_origin(sp: SurfacePoint, n: vec3<f32>) -> vec3<f32> {
    let offset = n * dot(abs(n), sp.error);
    let po = sp.p + offset;
    var out = po;
    for (var i = 0u; i < 3u; i++) {
        if offset[i] > 0.0 {
            out[i] = next_up(po[i]);
        } else if offset[i] < 0.0 {
            out[i] = -next_up(-po[i]);
        }
    }
    return out;
}

fn spawn_ray(sp: SurfacePoint, ng: vec3<f32>, dir: vec3<f32>) -> Ray {
    let n = select(ng, -ng, dot(ng, dir) < 0.0);
    return Ray(offset_ray_origin(sp, n), dir);
}

// ---- traversal ----

// A ray prepared for slab tests and the watertight triangle test.
struct TraceRay {
    origin: vec3<f32>,
    inv_dir: vec3<f32>,
    negative: vec3<bool>,
    // WatertightRay: axis permutation and shear.
    kx: u32,
    ky: u32,
    kz: u32,
    shear: vec3<f32>,
}

fn prepare_ray(ray: Ray) -> TraceRay {
    let d = ray.dir;
    let inv_dir = 1.0 / d;
    let ad = abs(d);
    var kz = 2u;
    if ad.x > ad.y {
        if ad.x > ad.z {
            kz = 0u;
        }
    } else if ad.y > ad.z {
        kz = 1u;
    }
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let k = kx;
        kx = ky;
        ky = k;
    }
    let shear = vec3<f32>(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]);
    return TraceRay(ray.origin, inv_dir, inv_dir < vec3<f32>(0.0), kx, ky, kz, shear);
}

// Aabb::intersect_ray (Ize 2013): the entry distance, or -1 for a miss.
fn slab(bmin: vec3<f32>, bmax: vec3<f32>, r: TraceRay, t_max: f32) -> f32 {
    let near = (select(bmin, bmax, r.negative) - r.origin) * r.inv_dir;
    let far = (select(bmax, bmin, r.negative) - r.origin) * r.inv_dir;
    var t_enter = 0.0;
    var t_exit = t_max;
    for (var i = 0u; i < 3u; i++) {
        // Written so that a NaN (origin on a plane, direction 0) keeps the running value.
        if near[i] > t_enter {
            t_enter = near[i];
        }
        if far[i] < t_exit {
            t_exit = far[i];
        }
    }
    if t_enter <= t_exit * ROBUST_SLAB_SCALE {
        return t_enter;
    }
    return -1.0;
}

// a * b - c * d with one rounding error, by Kahan's algorithm with fma.
fn difference_of_products(a: f32, b: f32, c: f32, d: f32) -> f32 {
    let cd = c * d;
    let err = fma(c, d, -cd);
    return fma(a, b, -cd) - err;
}

// The watertight test (Woop et al. 2013), as Triangle::intersect: (t, u, v), t < 0 for a miss.
fn intersect_triangle(tri: GpuTriangle, r: TraceRay, t_max: f32) -> vec3<f32> {
    let a = tri.v0 - r.origin;
    let b = tri.v1 - r.origin;
    let c = tri.v2 - r.origin;
    // The sheared coordinates of the three vertices, by axis; the z coordinates before the
    // shear's scaling too (lengths, for the error bound).
    let x = vec3<f32>(a[r.kx], b[r.kx], c[r.kx]);
    let y = vec3<f32>(a[r.ky], b[r.ky], c[r.ky]);
    let raw_z = vec3<f32>(a[r.kz], b[r.kz], c[r.kz]);
    let sx = x - r.shear.x * raw_z;
    let sy = y - r.shear.y * raw_z;
    let sz = r.shear.z * raw_z;
    let h = woop_2d(sx, sy, sz, max3(abs(raw_z)), r, t_max, false, 1.0);
    if h.w == 0.0 {
        return h.xyz;
    }
    // An edge function zero (a ray through an edge or vertex), subnormal or not finite, or T or
    // 1/det out of f32's normal range (scenes beyond about 10^±12): the CPU goes on in f64;
    // WGSL has no portable f64, so the same floats are multiplied by powers of two that bring
    // their largest to [1, 2) (the x and y by one, z by another). That is exact, unless a
    // coordinate far smaller than the largest falls below 2^-126, and it moves every product
    // back into range. Unlike the CPU's f64, the edge functions are still rounded f32 products.
    let xy_scale = pow2_normalizer(max(max3(abs(sx)), max3(abs(sy))), 254);
    // Kept below 2^127 so that its inverse, the factor back to `t`, is a normal f32.
    let z_scale = pow2_normalizer(max3(abs(sz)), 253);
    let z_unscale = bitcast<f32>((254u - (bitcast<u32>(z_scale) >> 23u)) << 23u);
    let s = woop_2d(sx * xy_scale, sy * xy_scale, sz * z_scale, max3(abs(raw_z)) * xy_scale, r, t_max, true, z_unscale);
    return s.xyz;
}

// The 2D part of the watertight test, from the sheared vertices (x, y and z by vertex) and the
// largest |z| before the shear's scaling (`shear_z`), all in units where `t` is the z unit times
// `t_unscale`. (t, u, v, 0) for a hit, (-1, 0, 0, 0) for a miss, and w = 1 where `careful` is
// false and the plain arithmetic cannot decide.
fn woop_2d(
    x: vec3<f32>,
    y: vec3<f32>,
    z: vec3<f32>,
    shear_z: f32,
    r: TraceRay,
    t_max: f32,
    careful: bool,
    t_unscale: f32,
) -> vec4<f32> {
    let miss = vec4<f32>(-1.0, 0.0, 0.0, 0.0);
    var u = x.z * y.y - y.z * x.y;
    var v = x.x * y.z - y.x * x.z;
    var w = x.y * y.x - y.y * x.x;
    if careful {
        // Products of the scaled floats round as those of the floats did (barring subnormals),
        // so an edge shared with a triangle that took the plain path gets the same sign; zeros
        // get Kahan's, as before. (This, like watertightness itself, assumes the compiler
        // evaluates `a * b - c * d` alike wherever it appears, fused or not.)
        if u == 0.0 || v == 0.0 || w == 0.0 {
            u = difference_of_products(x.z, y.y, y.z, x.y);
            v = difference_of_products(x.x, y.z, y.x, x.z);
            w = difference_of_products(x.y, y.x, y.y, x.x);
        }
    } else if !(is_normal_f(u) && is_normal_f(v) && is_normal_f(w)) {
        return vec4<f32>(-1.0, 0.0, 0.0, 1.0);
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return miss;
    }
    let det = u + v + w;
    if det == 0.0 {
        return miss;
    }
    let t_scaled = u * z.x + v * z.y + w * z.z;
    let rcp = 1.0 / det;
    if !careful && !(is_normal_f(t_scaled) && is_normal_f(rcp)) {
        return vec4<f32>(-1.0, 0.0, 0.0, 1.0);
    }
    let t_here = t_scaled * rcp;
    let t = t_here * t_unscale;
    // Bits decide finiteness: WGSL may assume no NaN or infinity in the comparisons.
    if !(is_finite_f(t) && t > 0.0 && t <= t_max) {
        return miss;
    }
    // t is conservatively positive (pbrt-v4, section 6.8.7, with the shear's term in length
    // units as on the CPU): a ray leaving a surface cannot hit it again at a t of rounding noise.
    let max_z = max3(abs(z));
    let max_x = max3(abs(x));
    let max_y = max3(abs(y));
    let delta_z = GAMMA3 * max_z;
    let delta_x = GAMMA5 * (max_x + abs(r.shear.x) * shear_z);
    let delta_y = GAMMA5 * (max_y + abs(r.shear.y) * shear_z);
    let delta_e = 2.0 * (GAMMA2 * max_x * max_y + delta_y * max_x + delta_x * max_y);
    let max_e = max3(abs(vec3<f32>(u, v, w)));
    // t_error_bound of geometry/triangle.rs, which is f64 there; here in f32, grouped so that no
    // product grows as the cube of the scene's size: max_e / |det| lies in [1/3, 1].
    let delta_t = 3.0 * ((GAMMA3 * max_z + delta_z) * (max_e * abs(rcp)) + (delta_e * abs(rcp)) * max_z);
    if t_here <= delta_t {
        return miss;
    }
    return vec4<f32>(t, v * rcp, w * rcp, 0.0);
}

// pow2_normalizer of geometry/aabb.rs, with p's biased exponent kept in [1, max_biased] (254
// there): a power of two p with p * m in [1, 2) for normal m below 2^127, from the exponent
// bits. m of 2^127 or more gets 2^-126 (p * m in [2, 4)), subnormal m and zero
// 2^(max_biased - 127), infinity and NaN 2^-126 (they stay what they are).
fn pow2_normalizer(m: f32, max_biased: i32) -> f32 {
    let biased = i32((bitcast<u32>(m) >> 23u) & 0xffu);
    return bitcast<f32>(u32(clamp(254 - biased, 1, max_biased)) << 23u);
}

// The box-culling slack of src/bvh/trace/mod.rs (cull_slack) for a tree whose box is lo..hi, with each length taken on the vector
// divided by its largest component (the CPU takes them in f64): plain lengths overflow beyond
// about 1e19 and underflow below 1e-19, which made the slack NaN.
fn cull_slack_in(r: Ray, lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let far = max(abs(lo - r.origin), abs(hi - r.origin));
    let m_far = max3(far);
    let m_dir = max3(abs(r.dir));
    if m_far == 0.0 {
        return 0.0;
    }
    return CULL_ABS_SLACK * (m_far / m_dir) * (length(far / m_far) / length(r.dir / m_dir));
}

// Triangle::unit_normal: where the squared length of the edges' cross product leaves f32's
// normal range (edges beyond about 1e9 or below 3e-10), the edges are first scaled by a power of
// two; plain normalisation gave zero there, which ended such paths black.
fn unit_normal(v0: vec3<f32>, v1: vec3<f32>, v2: vec3<f32>) -> vec3<f32> {
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let n = cross(e1, e2);
    let l2 = dot(n, n);
    if l2 >= 1.17549435e-38 && l2 <= 3.40282347e38 {
        return normalize_or_zero(n);
    }
    let largest = max(max3(abs(e1)), max3(abs(e2)));
    if !(is_finite_f(largest) && largest > 0.0) {
        return vec3<f32>(0.0);
    }
    let s = pow2_normalizer(largest, 254);
    return normalize_or_zero(cross(e1 * s, e2 * s));
}

struct Hit {
    t: f32,
    // Triangle position (in the form's order); INVALID_INDEX for none.
    index: u32,
    u: f32,
    v: f32,
    // The instance hit (0 in a flat scene).
    instance: u32,
}

// No hit yet, closer than t_max.
fn no_hit(t_max: f32) -> Hit {
    return Hit(t_max, INVALID_INDEX, 0.0, 0.0, 0u);
}

// Whether the triangle test's result `h` at position `i` of the instance at position `inst` is a closer hit
// than `best` (whose t is the query's t_max while it has none): nearer, or as near with a lower
// instance, then primitive id, so that every tree form finds the same hit as the CPU.
fn beats(h: vec3<f32>, i: u32, inst: u32, best: Hit) -> bool {
    if !(h.x > 0.0) {
        return false;
    }
    if h.x < best.t {
        return true;
    }
    if h.x != best.t {
        return false;
    }
    if best.index == INVALID_INDEX {
        return true;
    }
    if inst != best.instance {
        // Instances by id, not by position.
        return HAS_INSTANCES && instances[inst].id < instances[best.instance].id;
    }
    return prim_ids[i] < prim_ids[best.index];
}

// Triangle position `i` tested against the ray: its hit where it beats `best` and its cut-out
// mask (tested only then) keeps it, else `best` itself. Both traversals' leaf test.
// `inst` is the instance traced (0 in a flat scene) and `inst_material` its material override
// (INVALID_INDEX: none).
fn try_triangle(i: u32, inst: u32, inst_material: u32, r: TraceRay, best: Hit) -> Hit {
    let tri = triangles[i];
    let h = intersect_triangle(tri, r, best.t);
    if beats(h, i, inst, best) {
        if HAS_CUTOUTS && tri.cutout != 0u && cut_out(i, select(tri.material, inst_material, inst_material != INVALID_INDEX), h.y, h.z) {
            return best;
        }
        return Hit(h.x, i, h.y, h.z, inst);
    }
    return best;
}

// ---- two levels: the top-level tree over instances ----

// The linear part of an affine map given by its columns x, y, z applied to `v`, as glam's
// Affine3A: the axes scaled and summed in order (the translation, where wanted, added last).
fn linear(x: vec3<f32>, y: vec3<f32>, z: vec3<f32>, v: vec3<f32>) -> vec3<f32> {
    return x * v.x + y * v.y + z * v.z;
}

// The ray in the instance's object space; its direction is not renormalised, so t is the same
// in both spaces.
fn inst_to_object(inst: GpuInstance, ray: Ray) -> Ray {
    let origin = linear(inst.to_object_x, inst.to_object_y, inst.to_object_z, ray.origin) + inst.to_object_t;
    return Ray(origin, linear(inst.to_object_x, inst.to_object_y, inst.to_object_z, ray.dir));
}

fn inst_to_world(inst: GpuInstance, p: vec3<f32>) -> vec3<f32> {
    return linear(inst.to_world_x, inst.to_world_y, inst.to_world_z, p) + inst.to_world_t;
}

// The instance at position `k` traced for a better hit than `best` (its t the limit): the ray
// carried into its object space, through its mesh's tree (`traverse_tree`, the form's), leaving
// out `skip`'s triangle where `skip` names this instance.
fn visit_instance(k: u32, ray: Ray, best: Hit, skip: vec2<u32>, any: bool) -> Hit {
    let inst = instances[k];
    if inst.root == INVALID_INDEX {
        return best; // a mesh without triangles
    }
    let s = select(INVALID_INDEX, skip.y, skip.x == k);
    return traverse_tree(inst.root, inst_to_object(inst, ray), best, s, any, k, inst.material);
}

// The closest hit with 0 < t <= t_max, leaving out the triangle `skip` (instance position,
// triangle position; INVALID_INDEX triangle: none): the scene's one tree, or its two levels
// (`traverse_instances`, the form's).
fn closest_hit(ray: Ray, t_max: f32, skip: vec2<u32>) -> Hit {
    if HAS_INSTANCES {
        return traverse_instances(ray, t_max, skip, false);
    }
    return traverse_tree(0u, ray, no_hit(t_max), skip.y, false, 0u, INVALID_INDEX);
}

fn occluded(ray: Ray, t_max: f32, skip: vec2<u32>) -> bool {
    if HAS_INSTANCES {
        return traverse_instances(ray, t_max, skip, true).index != INVALID_INDEX;
    }
    return traverse_tree(0u, ray, no_hit(t_max), skip.y, true, 0u, INVALID_INDEX).index != INVALID_INDEX;
}

// ---- textures: src/texture/mod.rs ----

// Index `i` (integer-valued) wrapped into 0..n: 0 repeat, 1 clamp, 2 mirror.
fn tex_wrap(i: f32, n: u32, wrap: u32) -> u32 {
    let nf = f32(n);
    var k: f32;
    if wrap == 1u {
        k = clamp(i, 0.0, nf - 1.0);
    } else if wrap == 2u {
        let m = i - 2.0 * nf * floor(i / (2.0 * nf));
        k = select(m, 2.0 * nf - 1.0 - m, m >= nf);
    } else {
        k = i - nf * floor(i / nf);
    }
    return min(u32(max(k, 0.0)), n - 1u);
}

fn tex_texel(header: u32, x: u32, y: u32, srgb: bool) -> vec4<f32> {
    let offset = textures[header];
    let i = y * textures[header + 1u] + x;
    if (textures[header + 3u] & 1u) != 0u {
        let w = offset + 4u * i;
        return vec4<f32>(
            bitcast<f32>(textures[w]),
            bitcast<f32>(textures[w + 1u]),
            bitcast<f32>(textures[w + 2u]),
            bitcast<f32>(textures[w + 3u]),
        );
    }
    let p = textures[offset + i];
    let code = vec4<u32>(p & 255u, (p >> 8u) & 255u, (p >> 16u) & 255u, p >> 24u);
    if srgb {
        return vec4<f32>(
            bitcast<f32>(textures[code.x]),
            bitcast<f32>(textures[code.y]),
            bitcast<f32>(textures[code.z]),
            f32(code.w) / 255.0,
        );
    }
    return vec4<f32>(code) / 255.0;
}

// Texture::sample for a packed reference (gpu_texture_ref): bilinear, v up from the bottom row.
fn tex_sample(tex: u32, uv: vec2<f32>) -> vec4<f32> {
    let header = 256u + 4u * (tex & 0xffffffu);
    let wrap = (tex >> 24u) & 3u;
    let srgb = ((tex >> 26u) & 1u) != 0u;
    let w = textures[header + 1u];
    let h = textures[header + 2u];
    let x = uv.x * f32(w) - 0.5;
    let y = (1.0 - uv.y) * f32(h) - 0.5;
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let c0 = tex_wrap(x0, w, wrap);
    let c1 = tex_wrap(x0 + 1.0, w, wrap);
    let r0 = tex_wrap(y0, h, wrap);
    let r1 = tex_wrap(y0 + 1.0, h, wrap);
    let top = tex_texel(header, c0, r0, srgb) * (1.0 - fx) + tex_texel(header, c1, r0, srgb) * fx;
    let bottom = tex_texel(header, c0, r1, srgb) * (1.0 - fx) + tex_texel(header, c1, r1, srgb) * fx;
    return top * (1.0 - fy) + bottom * fy;
}

// Channel (bits 27 and 28 of the packed reference, gpu_texture_channel) of a lookup.
fn tex_channel(tex: u32, uv: vec2<f32>) -> f32 {
    return tex_sample(tex, uv)[(tex >> 27u) & 3u];
}

// RenderMaterial::bsdf_at: the coated material's roughness (α times its square) and metallic
// textures, then the albedo, Schlick F0 or base colour times the base colour texture.
fn textured(m: GpuMaterial, uv: vec2<f32>) -> GpuMaterial {
    var mat = m;
    if mat.kind == MAT_COATED {
        if mat.metallic_tex != INVALID_INDEX {
            mat.k.x *= tex_channel(mat.metallic_tex, uv);
        }
        if mat.roughness_tex != INVALID_INDEX {
            let r = tex_channel(mat.roughness_tex, uv);
            mat.alpha *= r * r;
        }
    }
    if mat.base_color_tex != INVALID_INDEX && (mat.kind == MAT_DIFFUSE || mat.kind == MAT_COATED
        || (mat.kind == MAT_CONDUCTOR && (mat.flags & MAT_COMPLEX_FRESNEL) == 0u)) {
        mat.albedo *= tex_sample(mat.base_color_tex, uv).xyz;
    }
    return mat;
}

// The texture coordinates of leaf triangle `index` at barycentrics (u, v).
fn triangle_uv(index: u32, u: f32, v: f32) -> vec2<f32> {
    let b = 6u * index;
    let a = vec2<f32>(uvs[b], uvs[b + 1u]);
    let c1 = vec2<f32>(uvs[b + 2u], uvs[b + 3u]);
    let c2 = vec2<f32>(uvs[b + 4u], uvs[b + 5u]);
    return (1.0 - u - v) * a + u * c1 + v * c2;
}

// Cutouts::cut: whether leaf triangle `index`, of a masked material `material`, is cut out
// at (u, v) by the mask (the alpha channel where the texture has one, else its first channel).
// The caller tests the triangle's `cutout` flag first, from the copy it intersected.
fn cut_out(index: u32, material: u32, u: f32, v: f32) -> bool {
    let mat = materials[material];
    if mat.alpha_tex == INVALID_INDEX {
        return false; // an instance's opaque override of a masked mesh
    }
    let t = tex_sample(mat.alpha_tex, triangle_uv(index, u, v));
    let header = 256u + 4u * (mat.alpha_tex & 0xffffffu);
    let coverage = select(t.x, t.w, (textures[header + 3u] & 2u) != 0u);
    return coverage < mat.alpha_cutoff;
}

// RenderMaterial::shading_normal's normal map: `n` turned by the tangent-space map in the
// triangle's frame (directions of increasing u and v, made orthonormal about n), on ng's side;
// zero where the frame or the result is degenerate.
fn normal_mapped(index: u32, u: f32, v: f32, tri: GpuTriangle, mat: GpuMaterial, n: vec3<f32>, ng: vec3<f32>) -> vec3<f32> {
    let b = 6u * index;
    let uv0 = vec2<f32>(uvs[b], uvs[b + 1u]);
    let duv1 = vec2<f32>(uvs[b + 2u], uvs[b + 3u]) - uv0;
    let duv2 = vec2<f32>(uvs[b + 4u], uvs[b + 5u]) - uv0;
    let det = duv1.x * duv2.y - duv1.y * duv2.x;
    let zero = vec3<f32>(0.0);
    if det == 0.0 || !is_finite_f(det) {
        return zero;
    }
    let dp1 = tri.v1 - tri.v0;
    let dp2 = tri.v2 - tri.v0;
    let tangent_raw = (dp1 * duv2.y - dp2 * duv1.y) / det;
    let bitangent = (dp2 * duv1.x - dp1 * duv2.x) / det;
    let tangent = normalize_or_zero(tangent_raw - n * dot(n, tangent_raw));
    if all(tangent == zero) {
        return zero;
    }
    var bt = cross(n, tangent);
    if dot(bt, bitangent) < 0.0 {
        bt = -bt;
    }
    // The hit's coordinates from the ones read above, not read again (triangle_uv's value).
    let m = tex_sample(mat.normal_tex, uv0 + u * duv1 + v * duv2).xyz * 2.0 - vec3<f32>(1.0);
    let mapped = normalize_or_zero(tangent * (m.x * mat.normal_scale) + bt * (m.y * mat.normal_scale) + n * m.z);
    return select(mapped, -mapped, dot(mapped, ng) < 0.0);
}

// ---- the environment map: src/render/environment.rs ----

// The map's frame from the world's.
fn env_local(d: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(params.env_x, d), dot(params.env_y, d), dot(params.env_z, d));
}

// direction_to_uv: u = atan2(x, -z) / 2π in [0, 1), v = acos(y) / π.
fn env_uv(d: vec3<f32>) -> vec2<f32> {
    var u = atan2(d.x, -d.z) * (0.5 / PI);
    if u < 0.0 {
        u += 1.0;
    }
    if u >= 1.0 {
        u = 0.0;
    }
    return vec2<f32>(u, acos(clamp(d.y, -1.0, 1.0)) * FRAC_1_PI);
}

fn env_texel(c: u32, r: u32) -> vec3<f32> {
    let i = 3u * (r * params.env_width + c);
    return vec3<f32>(env_map[i], env_map[i + 1u], env_map[i + 2u]);
}

// The rows of cells in the map's distribution: sampling_rows in src/texture/environment.rs.
fn env_rows() -> u32 {
    return max(params.env_height, 2u) - 1u;
}

// EnvironmentMap::eval: bilinear between texels, column j at u = (j + 0.5) / W (wrapping) and
// row i at v = i / (H - 1).
fn env_eval(dir: vec3<f32>) -> vec3<f32> {
    let uv = env_uv(env_local(dir));
    let w = f32(params.env_width);
    let h = f32(params.env_height);
    let x = uv.x * w - 0.5;
    let y = clamp(uv.y * (h - 1.0), 0.0, h - 1.0);
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let iw = i32(params.env_width);
    let c0 = u32(((i32(x0) % iw) + iw) % iw);
    let c1 = u32(((i32(x0) + 1) % iw + iw) % iw);
    let r0 = u32(y0);
    let r1 = min(r0 + 1u, params.env_height - 1u);
    let top = env_texel(c0, r0) * (1.0 - fx) + env_texel(c1, r0) * fx;
    let bottom = env_texel(c0, r1) * (1.0 - fx) + env_texel(c1, r1) * fx;
    return top * (1.0 - fy) + bottom * fy;
}

// EnvironmentMap::pdf: the density per steradian of drawing world direction `dir`; the cell as
// Distribution::pdf_at finds it.
fn env_pdf(dir: vec3<f32>) -> f32 {
    let d = env_local(dir);
    let sin_theta = sqrt(d.x * d.x + d.z * d.z);
    if !(sin_theta > 0.0) {
        return 0.0;
    }
    let uv = env_uv(d);
    let rows = env_rows();
    var x = uv.x * f32(params.env_width) - 0.5;
    if x < 0.0 {
        x += f32(params.env_width);
    }
    let c = min(u32(x), params.env_width - 1u);
    let r = min(u32(uv.y * f32(rows)), rows - 1u);
    let pdf = env_map[3u * params.env_width * params.env_height + r * params.env_width + c];
    return pdf / (2.0 * PI * PI * sin_theta);
}

// In a CDF of count + 1 values at env_map[start], the interval holding u (partition_point).
fn env_cdf_find(start: u32, count: u32, u: f32) -> u32 {
    var lo = 0u;
    var hi = count + 1u;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if env_map[start + mid] <= u {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return clamp(lo, 1u, count) - 1u;
}

fn env_within(lo: f32, hi: f32, x: f32) -> f32 {
    if hi > lo {
        return clamp((x - lo) / (hi - lo), 0.0, 1.0);
    }
    return 0.5;
}

fn next_down(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) - 1u);
}

// EnvironmentMap::sample: a world direction in xyz and its density per steradian in w (0: none).
fn env_sample(u: vec2<f32>) -> vec4<f32> {
    let w = params.env_width;
    let h = params.env_height;
    let rows = env_rows();
    let marginal = 3u * w * h + w * rows;
    let r = env_cdf_find(marginal, rows, u.y);
    let row = marginal + rows + 1u + r * (w + 1u);
    let c = env_cdf_find(row, w, u.x);
    let dv = env_within(env_map[marginal + r], env_map[marginal + r + 1u], u.y);
    let du = env_within(env_map[row + c], env_map[row + c + 1u], u.x);
    // Kept inside the cell, which starts at column c's centre (Distribution::sample).
    let x = min(f32(c) + du, next_down(f32(c + 1u)));
    var su = (x + 0.5) / f32(w);
    if su >= 1.0 {
        su -= 1.0;
    }
    let uv = vec2<f32>(su, min((f32(r) + dv) / f32(rows), next_down(f32(r + 1u) / f32(rows))));
    let p = env_map[3u * w * h + r * w + c];
    let phi = 2.0 * PI * uv.x;
    let theta = PI * uv.y;
    let sin_theta = sin(theta);
    if !(p > 0.0) || !(sin_theta > 0.0) {
        return vec4<f32>(0.0);
    }
    let local = vec3<f32>(sin(phi) * sin_theta, cos(theta), -cos(phi) * sin_theta);
    let world = params.env_x * local.x + params.env_y * local.y + params.env_z * local.z;
    return vec4<f32>(world, p / (2.0 * PI * PI * sin_theta));
}

// The radiance arriving along `dir` from the environment after a bounce sampled with density
// prev_pdf (RenderScene::escaped).
fn escaped(dir: vec3<f32>, prev_pdf: f32, prev_delta: bool) -> vec3<f32> {
    if HAS_ENV_MAP && params.env_width > 0u {
        let le = params.environment * env_eval(dir);
        if prev_delta {
            return le;
        }
        return le * power_heuristic(prev_pdf, params.env_select * env_pdf(dir));
    }
    return params.environment;
}

// The environment-map half of direct_light: a direction drawn from the map, weighted against
// the BSDF. The shadow ray leaves along the normal, as a bounce does, and has no end.
fn direct_env(
    mat: GpuMaterial,
    frame: Frame,
    sp: SurfacePoint,
    ng: vec3<f32>,
    check: bool,
    wo_ng: f32,
    wo: vec3<f32>,
    beta: vec3<f32>,
    u: vec2<f32>,
    surface: vec2<u32>,
) -> vec4<f32> {
    let s = env_sample(u);
    if !(s.w > 0.0) {
        return vec4<f32>(0.0);
    }
    let wi_world = s.xyz;
    let le = params.environment * env_eval(wi_world);
    let wi = to_local(frame, wi_world);
    if check && !agrees(dot(ng, wi_world), wo_ng, wi.z, wo.z) {
        return vec4<f32>(0.0);
    }
    let f = bsdf_eval(mat, wo, wi);
    if max3(f) <= 0.0 || max3(le) <= 0.0 {
        return vec4<f32>(0.0);
    }
    if occluded(spawn_ray(sp, ng, wi_world), T_FAR, surface) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let p_light = params.env_select * s.w;
    let w = power_heuristic(p_light, bsdf_pdf(mat, wo, wi));
    return vec4<f32>(beta * f * abs(wi.z) * le * (w / p_light), 1.0);
}

// ---- the integrator ----

// Lights::sample's choice: the first light whose CDF value exceeds u (binary search).
fn choose_light(u: f32) -> u32 {
    var lo = 0u;
    var hi = params.light_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if lights[mid].cdf <= u {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return min(lo, params.light_count - 1u);
}

// RenderScene::direct_light: one light sample, MIS-weighted against the BSDF. Returns the
// contribution in xyz and the rays traced (0 or 1) in w.
// agrees() of src/render/integrator.rs: the shading frame and the geometry agree on what a
// scattering does, and wi is not along the surface.
fn agrees(wi_ng: f32, wo_ng: f32, wi_n: f32, wo_n: f32) -> bool {
    return ((wi_ng > 0.0) == (wo_ng > 0.0)) == ((wi_n > 0.0) == (wo_n > 0.0)) && wi_ng != 0.0;
}

// The inverse transpose of instance `m`'s placement applied to the object-space normal `n`,
// normalised (as Geometry::intersect_from places a mesh's vertex normals).
fn inst_normal(m: GpuInstance, n: vec3<f32>) -> vec3<f32> {
    return normalize_or_zero(vec3<f32>(dot(m.to_object_x, n), dot(m.to_object_y, n), dot(m.to_object_z, n)));
}

// SurfaceHit::shading_normal: the vertex normals of leaf `index` (of instance `inst`, in a
// two-level scene) interpolated at (u, v), normalised and turned to ng's side; zero where a
// vertex has none or they cancel. A mirroring instance swaps two vertices and the
// barycentrics with them, which leaves the interpolation as it is.
fn shading_normal(index: u32, inst: u32, u: f32, v: f32, ng: vec3<f32>) -> vec3<f32> {
    let b = 9u * index;
    var a = vec3<f32>(normals[b], normals[b + 1u], normals[b + 2u]);
    var c1 = vec3<f32>(normals[b + 3u], normals[b + 4u], normals[b + 5u]);
    var c2 = vec3<f32>(normals[b + 6u], normals[b + 7u], normals[b + 8u]);
    if HAS_INSTANCES {
        let m = instances[inst];
        a = inst_normal(m, a);
        c1 = inst_normal(m, c1);
        c2 = inst_normal(m, c2);
    }
    let zero = vec3<f32>(0.0);
    if all(a == zero) || all(c1 == zero) || all(c2 == zero) {
        return zero;
    }
    let n = (1.0 - u - v) * a + u * c1 + v * c2;
    let len2 = dot(n, n);
    if !(len2 > 0.0) || !is_finite_f(len2) {
        return zero;
    }
    let m = n * (1.0 / sqrt(len2));
    return select(m, -m, dot(m, ng) < 0.0);
}

fn direct_light(
    mat: GpuMaterial,
    frame: Frame,
    sp: SurfacePoint,
    ng: vec3<f32>,
    check: bool,
    wo_ng: f32,
    wo: vec3<f32>,
    beta: vec3<f32>,
    rng: ptr<function, Rng>,
    surface: vec2<u32>,
) -> vec4<f32> {
    var u_select = rng_f32(rng);
    let u = rng_vec2(rng);
    var area_select = 1.0;
    if HAS_ENV_MAP && params.env_width > 0u {
        if u_select < params.env_select {
            return direct_env(mat, frame, sp, ng, check, wo_ng, wo, beta, u, surface);
        }
        u_select = min((u_select - params.env_select) / (1.0 - params.env_select), 1.0 - 5.9604645e-8);
        area_select = 1.0 - params.env_select;
    }
    let light = lights[choose_light(u_select)];
    let b = uniform_triangle(u);
    let lp = point_with_error(light.v0, light.v1, light.v2, b.y, b.z);
    var radiance = light.radiance;
    if HAS_TEXTURES && light.emission_tex != INVALID_INDEX {
        // As triangle_uv interpolates (Lights::sample on the CPU).
        let uv = (1.0 - b.y - b.z) * vec2<f32>(light.uvs[0], light.uvs[1]) + b.y * vec2<f32>(light.uvs[2], light.uvs[3])
            + b.z * vec2<f32>(light.uvs[4], light.uvs[5]);
        radiance *= tex_sample(light.emission_tex, uv).xyz;
    }
    let to = lp.p - sp.p;
    let dist = robust_length(to);
    if !(dist > 0.0 && is_finite_f(dist)) {
        return vec4<f32>(0.0);
    }
    let wi_world = to / dist;
    let cos_light = dot(light.normal, -wi_world);
    if !(cos_light > 0.0 || (light.two_sided != 0u && cos_light < 0.0)) {
        return vec4<f32>(0.0);
    }
    let wi = to_local(frame, wi_world);
    if check && !agrees(dot(ng, wi_world), wo_ng, wi.z, wo.z) {
        return vec4<f32>(0.0);
    }
    let f = bsdf_eval(mat, wo, wi);
    if max3(f) <= 0.0 || max3(radiance) <= 0.0 {
        return vec4<f32>(0.0);
    }
    // As on the CPU: the shadow ray stays on the line from p to the light point, starting just
    // clear of the receiver (its error bound plus one rounding, along the ray) and stopping short
    // of the light's plane by the light point's error bound, and by SHADOW_T_MAX.
    let cos_receiver = abs(dot(ng, wi_world));
    let clear = dot(abs(ng), sp.error + abs(sp.p) * GAMMA1) / cos_receiver;
    let from_surface = sp.p + wi_world * clear;
    let shadow = Ray(from_surface, lp.p - from_surface);
    let short_of_plane = dot(abs(light.normal), lp.error) / (abs(cos_light) * robust_length(shadow.dir));
    let t_max = (1.0 - short_of_plane) * SHADOW_T_MAX;
    if !(is_finite_f(clear) && clear < dist && t_max > 0.0) || occluded(shadow, t_max, surface) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let p_light = area_select * solid_angle_pdf(light.pdf_area, to, abs(cos_light));
    let w = power_heuristic(p_light, bsdf_pdf(mat, wo, wi));
    return vec4<f32>(beta * f * abs(wi.z) * radiance * (w / p_light), 1.0);
}

struct PathResult {
    l: vec3<f32>,
    rays: u32,
}

// RenderScene::radiance: a path of at most params.max_depth segments.
fn radiance(camera: Ray, rng: ptr<function, Rng>) -> PathResult {
    var l = vec3<f32>(0.0);
    var beta = vec3<f32>(1.0);
    var prev_pdf = 0.0;
    var prev_delta = true;
    var rays = 0u;
    var ray = camera;
    // The triangle the ray leaves, which it skips (as on the CPU); shadow rays skip theirs.
    var surface = vec2<u32>(0u, INVALID_INDEX);
    // The probability that next-event estimation picks an area light, not the map.
    var area_select = 1.0;
    var env_lit = false;
    if HAS_ENV_MAP && params.env_width > 0u {
        area_select = 1.0 - params.env_select;
        env_lit = true;
    }
    for (var depth = 1u; depth <= params.max_depth; depth++) {
        rays += 1u;
        let hit = closest_hit(ray, T_FAR, surface);
        if hit.index == INVALID_INDEX {
            if HAS_ENVIRONMENT {
                l += beta * escaped(ray.dir, prev_pdf, prev_delta);
            }
            break;
        }
        var tri = triangles[hit.index];
        var mirrors = false;
        if HAS_INSTANCES {
            // The triangle placed in the world (Triangle::placed, its vertex order kept: a
            // mirroring instance's normal is turned instead), its material and light density.
            let inst = instances[hit.instance];
            tri.v0 = inst_to_world(inst, tri.v0);
            tri.v1 = inst_to_world(inst, tri.v1);
            tri.v2 = inst_to_world(inst, tri.v2);
            if inst.material != INVALID_INDEX {
                tri.material = inst.material;
            }
            tri.light_pdf = 0.0;
            if inst.light_base != INVALID_INDEX {
                tri.light_pdf = light_pdfs[inst.light_base + prim_ids[hit.index]];
            }
            mirrors = inst.mirrors != 0u;
        }
        var ng = unit_normal(tri.v0, tri.v1, tri.v2);
        if all(ng == vec3<f32>(0.0)) {
            break;
        }
        if mirrors {
            ng = -ng;
        }
        let sp = point_with_error(tri.v0, tri.v1, tri.v2, hit.u, hit.v);
        let wo_world = -ray.dir;
        let front = dot(ng, wo_world) > 0.0;
        var mat = materials[tri.material];
        // (The references' AND is INVALID_INDEX, all ones, only where each is.)
        if HAS_TEXTURES && (mat.base_color_tex & mat.roughness_tex & mat.metallic_tex) != INVALID_INDEX {
            mat = textured(mat, triangle_uv(hit.index, hit.u, hit.v));
        }
        if (mat.flags & MAT_EMITS) != 0u && (front || (mat.flags & MAT_TWO_SIDED) != 0u) {
            var le = mat.emission;
            if HAS_TEXTURES && mat.emission_tex != INVALID_INDEX {
                le *= tex_sample(mat.emission_tex, triangle_uv(hit.index, hit.u, hit.v)).xyz;
            }
            if prev_delta {
                l += beta * le;
            } else {
                let p_light = area_select * solid_angle_pdf(tri.light_pdf, sp.p - ray.origin, abs(dot(ng, wo_world)));
                l += beta * le * power_heuristic(prev_pdf, p_light);
            }
        }
        if depth == params.max_depth || mat.kind == MAT_BLACK {
            break;
        }
        if mat.kind != MAT_DIELECTRIC && !front {
            break; // one-sided reflector seen from the back
        }
        // The shading normal where the view sees the same side of it as of the surface
        // (src/render/integrator.rs).
        let wo_ng = dot(ng, wo_world);
        var n = ng;
        var check = false;
        var ns = vec3<f32>(0.0);
        if HAS_SHADING_NORMALS {
            ns = shading_normal(hit.index, hit.instance, hit.u, hit.v, ng);
        }
        if HAS_TEXTURES && mat.normal_tex != INVALID_INDEX {
            let mapped = normal_mapped(hit.index, hit.u, hit.v, tri, mat, select(ns, ng, all(ns == vec3<f32>(0.0))), ng);
            if any(mapped != vec3<f32>(0.0)) {
                ns = mapped;
            }
        }
        if any(ns != vec3<f32>(0.0)) && (dot(ns, wo_world) > 0.0) == (wo_ng > 0.0) {
            n = ns;
            check = true;
        }
        let frame = frame_from_normal(n);
        let wo = to_local(frame, wo_world);
        if ((HAS_LIGHTS && params.light_count > 0u) || env_lit) && !mat_is_delta(mat) {
            let direct = direct_light(mat, frame, sp, ng, check, wo_ng, wo, beta, rng, vec2<u32>(hit.instance, hit.index));
            l += direct.xyz;
            rays += u32(direct.w);
        }
        let u = rng_vec2(rng);
        let u_lobe = rng_f32(rng);
        let s = bsdf_sample(mat, wo, u, u_lobe);
        if !s.ok || !(all_finite(s.weight) && max3(s.weight) > 0.0) {
            break;
        }
        let wi_world = normalize_glam(to_world(frame, s.wi));
        if check && !agrees(dot(ng, wi_world), wo_ng, s.wi.z, wo.z) {
            break;
        }
        beta *= s.weight;
        prev_pdf = s.pdf;
        prev_delta = s.is_delta;
        ray = spawn_ray(sp, ng, wi_world);
        surface = vec2<u32>(hit.instance, hit.index);
        if depth >= RR_DEPTH {
            let q = min(max3(beta), 0.95);
            if rng_f32(rng) >= q {
                break;
            }
            beta /= q;
        }
    }
    return PathResult(l, rays);
}

// Adds `v` to the 128-bit two's-complement fixed-point integer `limbs` (four 32-bit limbs,
// least significant first, in units of 2^-FILM_FRACTION_BITS): the film's exact sums
// (src/render/film.rs), which make the image of any split of the samples the same. `v` is
// rounded to the nearest unit, ties to even, as the CPU's `to_fixed` rounds; the caller has
// checked that |v| < FILM_SAMPLE_LIMIT (2^44), so `v` in units needs at most 94 bits.
fn add_fixed(limbs: ptr<function, array<u32, 12>>, base: u32, v: f32) {
    let bits = bitcast<u32>(v);
    let e = (bits >> 23u) & 0xffu;
    var m = bits & 0x7fffffu;
    if e != 0u {
        m = m | 0x800000u;
    }
    // |v| = m × 2^(max(e, 1) − 150), so |v| in units is m × 2^(max(e, 1) − 150 + FILM_FRACTION_BITS).
    let s = i32(max(e, 1u)) - 150 + FILM_FRACTION_BITS;
    var q = array<u32, 4>(0u, 0u, 0u, 0u);
    if s < 0 {
        let r = u32(-s);
        // m < 2^24: a shift by 25 or more leaves less than half a unit.
        if r <= 24u {
            var w = m >> r;
            let rest = m & ((1u << r) - 1u);
            let half = 1u << (r - 1u);
            if rest > half || (rest == half && (w & 1u) == 1u) {
                w = w + 1u;
            }
            q[0] = w;
        }
    } else {
        let t = u32(s);
        let limb = t / 32u;
        let shift = t % 32u;
        q[limb] = m << shift;
        if shift != 0u && limb < 3u {
            q[limb + 1u] = m >> (32u - shift);
        }
    }
    if (bits >> 31u) == 1u {
        // Two's complement: invert and add one.
        var carry = 1u;
        for (var i = 0u; i < 4u; i++) {
            let inverted = ~q[i];
            q[i] = inverted + carry;
            carry = select(0u, 1u, q[i] < inverted);
        }
    }
    var carry = 0u;
    for (var i = 0u; i < 4u; i++) {
        let a = (*limbs)[base + i];
        let s1 = a + q[i];
        let s2 = s1 + carry;
        carry = select(0u, 1u, s1 < a) + select(0u, 1u, s2 < s1);
        (*limbs)[base + i] = s2;
    }
}

@compute @workgroup_size(TRACE_WORKGROUP, TRACE_WORKGROUP)
fn trace(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.rect_width || gid.y >= params.rect_height {
        return;
    }
    // The image's pixel, which the random streams and the camera take; the film holds the
    // rectangle only.
    let px = params.origin_x + gid.x;
    let py = params.origin_y + gid.y;
    let pixel = py * params.width + px;
    let slot = gid.y * params.rect_width + gid.x;
    var acc = film[slot];
    var exact = acc.exact;
    let end = params.sample_start + params.sample_count;
    for (var s = params.sample_start; s < end; s++) {
        var rng = rng_for_sample(pixel, s);
        let film_pos = vec2<f32>(f32(px), f32(py)) + rng_vec2(&rng);
        let lens = rng_vec2(&rng);
        let path = radiance(camera_ray(film_pos, lens), &rng);
        acc.rays += path.rays;
        var l = path.l;
        // Film::add_sample: non-finite samples are counted and dropped; then the clamp (which
        // on the CPU turns an infinite sample into NaN, dropped all the same); then samples too
        // large for the exact sums are dropped as the CPU drops them.
        if !all_finite(l) {
            acc.non_finite += 1u;
            continue;
        }
        if params.clamp > 0.0 {
            let m = max3(l);
            if m > params.clamp {
                l *= params.clamp / m;
            }
        }
        if max3(abs(l)) >= FILM_SAMPLE_LIMIT {
            acc.non_finite += 1u;
            continue;
        }
        if acc.count == 0u {
            acc.shift = l;
        }
        let d = l - acc.shift;
        acc.sum += d;
        acc.sum_sq += d * d;
        acc.count += 1u;
        add_fixed(&exact, 0u, l.x);
        add_fixed(&exact, 4u, l.y);
        add_fixed(&exact, 8u, l.z);
    }
    acc.exact = exact;
    film[slot] = acc;
}
