// Materials and sampling for the path tracer: src/render/bsdf.rs and src/render/sampling.rs,
// function for function (see those files for the papers and the reasoning). Local frame: the
// geometric normal is +z; wo points to the previous path vertex, wi to the light.
//
// Concatenated after the variant's HAS_* constants (src/gpu/trace.rs) and before trace.wgsl;
// code for a material kind the scene lacks sits behind `if HAS_...` and is dropped by the compiler.
//
// WGSL lets implementations assume that no value is NaN or infinite, so every test for one
// reads the bits.

const PI: f32 = 3.14159265358979323846;
const FRAC_1_PI: f32 = 0.318309886183790671538;
const FRAC_PI_2: f32 = 1.57079632679489661923;
const FRAC_PI_4: f32 = 0.785398163397448309616;
// f32::MIN_POSITIVE, the smallest normal f32.
const MIN_POSITIVE: f32 = 1.17549435e-38;

fn is_finite_f(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// f32::is_normal: neither zero, subnormal, infinite nor NaN.
fn is_normal_f(x: f32) -> bool {
    let e = bitcast<u32>(x) & 0x7f800000u;
    return e != 0u && e != 0x7f800000u;
}

fn is_inf_f(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) == 0x7f800000u;
}

fn all_finite(v: vec3<f32>) -> bool {
    return is_finite_f(v.x) && is_finite_f(v.y) && is_finite_f(v.z);
}

fn max3(v: vec3<f32>) -> f32 {
    return max(max(v.x, v.y), v.z);
}

// f32::signum: the sign bit decides, so -0.0 gives -1 (WGSL's sign gives 0).
fn signum_f(x: f32) -> f32 {
    return select(1.0, -1.0, (bitcast<u32>(x) & 0x80000000u) != 0u);
}

// glam's normalize_or_zero: v / |v|, or zero when that is not finite.
fn normalize_or_zero(v: vec3<f32>) -> vec3<f32> {
    let rcp = 1.0 / sqrt(dot(v, v));
    if is_finite_f(rcp) && rcp > 0.0 {
        return v * rcp;
    }
    return vec3<f32>(0.0);
}

// glam's normalize: v times the reciprocal of its length.
fn normalize_glam(v: vec3<f32>) -> vec3<f32> {
    return v * (1.0 / sqrt(dot(v, v)));
}

// ---- sampling.rs ----

fn concentric_disk(u: vec2<f32>) -> vec2<f32> {
    let o = 2.0 * u - vec2<f32>(1.0);
    if o.x == 0.0 && o.y == 0.0 {
        return vec2<f32>(0.0);
    }
    var r: f32;
    var theta: f32;
    if abs(o.x) > abs(o.y) {
        r = o.x;
        theta = FRAC_PI_4 * (o.y / o.x);
    } else {
        r = o.y;
        theta = FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y);
    }
    return vec2<f32>(r * cos(theta), r * sin(theta));
}

fn cosine_hemisphere(u: vec2<f32>) -> vec3<f32> {
    let d = concentric_disk(u);
    let z = sqrt(max(1.0 - dot(d, d), 0.0));
    return vec3<f32>(d.x, d.y, z);
}

// Barycentrics (b0, b1, b2) uniform over a triangle (Heitz 2019).
fn uniform_triangle(u: vec2<f32>) -> vec3<f32> {
    var b0: f32;
    var b1: f32;
    if u.x < u.y {
        b0 = 0.5 * u.x;
        b1 = u.y - b0;
    } else {
        b1 = 0.5 * u.y;
        b0 = u.x - b1;
    }
    return vec3<f32>(b0, b1, max(1.0 - b0 - b1, 0.0));
}

// |v| also where |v|^2 overflows or underflows f32: robust_length in src/render/sampling.rs.
fn robust_length(v: vec3<f32>) -> f32 {
    let dist2 = dot(v, v);
    if is_normal_f(dist2) {
        return sqrt(dist2);
    }
    let m = max(max(abs(v.x), abs(v.y)), abs(v.z));
    if m > 0.0 && is_finite_f(m) {
        return m * length(v / m);
    }
    return m;
}

// pdf_area |to|^2 / cos, 0 for a light never sampled, finite past distances of 10^19:
// solid_angle_pdf in src/render/sampling.rs.
fn solid_angle_pdf(pdf_area: f32, to: vec3<f32>, cos_at_light: f32) -> f32 {
    if pdf_area == 0.0 {
        return 0.0;
    }
    let dist2 = dot(to, to);
    if is_normal_f(dist2) {
        return pdf_area * dist2 / cos_at_light;
    }
    let dist = robust_length(to);
    return pdf_area * dist * (dist / cos_at_light);
}

fn power_heuristic(pdf_f: f32, pdf_g: f32) -> f32 {
    if pdf_f == 0.0 {
        return 0.0;
    }
    if is_inf_f(pdf_f) && is_inf_f(pdf_g) {
        return 0.5;
    }
    let r = pdf_g / pdf_f;
    return 1.0 / (1.0 + r * r);
}

// An orthonormal frame (s, t, n), Duff et al. 2017, as glam's any_orthonormal_pair.
struct Frame {
    s: vec3<f32>,
    t: vec3<f32>,
    n: vec3<f32>,
}

fn frame_from_normal(n: vec3<f32>) -> Frame {
    let sign = signum_f(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let s = vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let t = vec3<f32>(b, sign + n.y * n.y * a, -n.y);
    return Frame(s, t, n);
}

fn to_local(f: Frame, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(v, f.s), dot(v, f.t), dot(v, f.n));
}

fn to_world(f: Frame, v: vec3<f32>) -> vec3<f32> {
    return f.s * v.x + f.t * v.y + f.n * v.z;
}

// ---- bsdf.rs ----

struct BsdfSample {
    wi: vec3<f32>,
    weight: vec3<f32>,
    pdf: f32,
    is_delta: bool,
    // false: no sample (the CPU's None).
    ok: bool,
}

fn no_sample() -> BsdfSample {
    return BsdfSample(vec3<f32>(0.0), vec3<f32>(0.0), 0.0, false, false);
}

fn same_side(a: vec3<f32>, b: vec3<f32>) -> bool {
    return a.z * b.z > 0.0;
}

fn flip_z(v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(v.x, v.y, -v.z);
}

fn reflect_about(w: vec3<f32>, m: vec3<f32>) -> vec3<f32> {
    return 2.0 * dot(w, m) * m - w;
}

fn mat_is_delta(m: GpuMaterial) -> bool {
    if m.kind == MAT_CONDUCTOR {
        return m.alpha < SMOOTH_ALPHA;
    }
    if m.kind == MAT_DIELECTRIC {
        return m.alpha < SMOOTH_ALPHA || m.ior == 1.0;
    }
    return false;
}

fn diffuse_sample(albedo: vec3<f32>, wo: vec3<f32>, u: vec2<f32>) -> BsdfSample {
    var wi = cosine_hemisphere(u);
    if wi.z == 0.0 {
        return no_sample();
    }
    if wo.z < 0.0 {
        wi = flip_z(wi);
    }
    return BsdfSample(wi, albedo, abs(wi.z) * FRAC_1_PI, false, true);
}

// GGX (isotropic), as the CPU's Ggx.
fn ggx_d(alpha: f32, m: vec3<f32>) -> f32 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let denom = m.x * m.x + m.y * m.y + a2 * m.z * m.z;
    return a2 / (PI * denom * denom);
}

fn stretched_len(alpha: f32, w: vec3<f32>) -> f32 {
    let a2 = alpha * alpha;
    return sqrt(w.z * w.z + a2 * (w.x * w.x + w.y * w.y));
}

fn g2_over_cos(alpha: f32, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    let qo = stretched_len(alpha, wo);
    let qi = stretched_len(alpha, wi);
    return 2.0 / (qo * abs(wi.z) + qi * abs(wo.z));
}

fn g2_over_g1(alpha: f32, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    let qo = stretched_len(alpha, wo);
    let qi = stretched_len(alpha, wi);
    let zo = abs(wo.z);
    let zi = abs(wi.z);
    return zi * (zo + qo) / (qo * zi + qi * zo);
}

fn visible_normal_pdf(alpha: f32, wo: vec3<f32>, m: vec3<f32>) -> f32 {
    let cos_om = dot(wo, m);
    if cos_om * wo.z <= 0.0 {
        return 0.0;
    }
    return 2.0 * abs(cos_om) * ggx_d(alpha, m) / (abs(wo.z) + stretched_len(alpha, wo));
}

// Heitz 2018, listing 1, isotropic.
fn sample_visible_normal(alpha: f32, wo: vec3<f32>, u: vec2<f32>) -> vec3<f32> {
    let a = alpha;
    let vh = normalize_glam(vec3<f32>(a * wo.x, a * wo.y, wo.z));
    let len2 = vh.x * vh.x + vh.y * vh.y;
    var t1 = vec3<f32>(1.0, 0.0, 0.0);
    if len2 > 0.0 {
        t1 = vec3<f32>(-vh.y, vh.x, 0.0) / sqrt(len2);
    }
    let t2 = cross(vh, t1);
    let r = sqrt(u.x);
    let phi = 2.0 * PI * u.y;
    let p1 = r * cos(phi);
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * sqrt(max(1.0 - p1 * p1, 0.0)) + s * r * sin(phi);
    let nh = p1 * t1 + p2 * t2 + sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh;
    return normalize_glam(vec3<f32>(a * nh.x, a * nh.y, max(nh.z, 0.0)));
}

// Lagarde 2013; powf(0.5) of the CPU written as sqrt (the same value, more accurate in WGSL).
fn fresnel_conductor(cos_theta: f32, eta: vec3<f32>, k: vec3<f32>) -> vec3<f32> {
    let c = clamp(cos_theta, 0.0, 1.0);
    let c2 = c * c;
    let s2 = 1.0 - c2;
    let eta2 = eta * eta;
    let k2 = k * k;
    let t0 = eta2 - k2 - vec3<f32>(s2);
    let a2b2 = sqrt(t0 * t0 + 4.0 * eta2 * k2);
    let a = sqrt(max(0.5 * (a2b2 + t0), vec3<f32>(0.0)));
    let t1 = a2b2 + vec3<f32>(c2);
    let t2 = 2.0 * c * a;
    let rs = (t1 - t2) / max(t1 + t2, vec3<f32>(MIN_POSITIVE));
    let t3 = c2 * a2b2 + vec3<f32>(s2 * s2);
    let t4 = t2 * s2;
    let rp = rs * (t3 - t4) / max(t3 + t4, vec3<f32>(MIN_POSITIVE));
    return 0.5 * (rs + rp);
}

fn conductor_fresnel(m: GpuMaterial, cos_theta: f32) -> vec3<f32> {
    if (m.flags & MAT_COMPLEX_FRESNEL) != 0u {
        return fresnel_conductor(cos_theta, m.albedo, m.k);
    }
    let x = 1.0 - clamp(cos_theta, 0.0, 1.0);
    let x2 = x * x;
    return m.albedo + (vec3<f32>(1.0) - m.albedo) * (x2 * x2 * x);
}

// (R, T) of a dielectric interface, as the CPU's fresnel_dielectric_rt.
fn fresnel_dielectric_rt(cos_in: f32, eta_in: f32) -> vec2<f32> {
    var cos_i = cos_in;
    var eta = eta_in;
    if cos_i < 0.0 {
        cos_i = -cos_i;
        eta = 1.0 / eta;
    }
    cos_i = min(cos_i, 1.0);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return vec2<f32>(1.0, 0.0);
    }
    let cos_t = sqrt(1.0 - sin2_t);
    let perp_sum = cos_i + eta * cos_t;
    let parl_sum = eta * cos_i + cos_t;
    let r_parl = (eta * cos_i - cos_t) / parl_sum;
    let r_perp = (cos_i - eta * cos_t) / perp_sum;
    let t = 2.0 * eta * cos_i * cos_t * (1.0 / (perp_sum * perp_sum) + 1.0 / (parl_sum * parl_sum));
    return vec2<f32>(0.5 * (r_parl * r_parl + r_perp * r_perp), t);
}

// The refracted direction in xyz and eta_t / eta_i in w; w = 0 under total internal reflection.
fn refract_dir(w: vec3<f32>, m_in: vec3<f32>, eta_in: f32) -> vec4<f32> {
    var cos_i = dot(w, m_in);
    var eta = eta_in;
    var m = m_in;
    if cos_i < 0.0 {
        cos_i = -cos_i;
        eta = 1.0 / eta;
        m = -m;
    }
    let sin2_t = max(1.0 - cos_i * cos_i, 0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return vec4<f32>(0.0);
    }
    let cos_t = sqrt(1.0 - sin2_t);
    return vec4<f32>(-w / eta + (cos_i / eta - cos_t) * m, eta);
}

fn conductor_eval(mat: GpuMaterial, wo_in: vec3<f32>, wi_in: vec3<f32>) -> vec3<f32> {
    if !same_side(wo_in, wi_in) {
        return vec3<f32>(0.0);
    }
    var wo = wo_in;
    var wi = wi_in;
    if wo.z < 0.0 {
        wo = flip_z(wo);
        wi = flip_z(wi);
    }
    let m = normalize_or_zero(wo + wi);
    if all(m == vec3<f32>(0.0)) {
        return vec3<f32>(0.0);
    }
    return conductor_fresnel(mat, dot(wo, m)) * (0.25 * ggx_d(mat.alpha, m) * g2_over_cos(mat.alpha, wo, wi));
}

fn conductor_pdf(alpha: f32, wo_in: vec3<f32>, wi_in: vec3<f32>) -> f32 {
    if !same_side(wo_in, wi_in) {
        return 0.0;
    }
    var wo = wo_in;
    var wi = wi_in;
    if wo.z < 0.0 {
        wo = flip_z(wo);
        wi = flip_z(wi);
    }
    let m = normalize_or_zero(wo + wi);
    if all(m == vec3<f32>(0.0)) {
        return 0.0;
    }
    return visible_normal_pdf(alpha, wo, m) / (4.0 * dot(wo, m));
}

fn conductor_sample(mat: GpuMaterial, wo: vec3<f32>, u: vec2<f32>) -> BsdfSample {
    let flipped = wo.z < 0.0;
    let wo_up = select(wo, flip_z(wo), flipped);
    let m = sample_visible_normal(mat.alpha, wo_up, u);
    let wi_up = reflect_about(wo_up, m);
    if wi_up.z <= 0.0 {
        return no_sample();
    }
    let wi = select(wi_up, flip_z(wi_up), flipped);
    let pdf = conductor_pdf(mat.alpha, wo, wi);
    if pdf <= 0.0 {
        return no_sample();
    }
    let weight = conductor_fresnel(mat, dot(wo_up, m)) * g2_over_g1(mat.alpha, wo_up, wi_up);
    return BsdfSample(wi, weight, pdf, false, true);
}

fn smooth_dielectric_sample(ior: f32, wo: vec3<f32>, u_lobe: f32) -> BsdfSample {
    let r = fresnel_dielectric_rt(wo.z, ior).x;
    if u_lobe < r {
        return BsdfSample(vec3<f32>(-wo.x, -wo.y, wo.z), vec3<f32>(1.0), r, true, true);
    }
    let refracted = refract_dir(wo, vec3<f32>(0.0, 0.0, 1.0), ior);
    if refracted.w == 0.0 || refracted.z == 0.0 {
        return no_sample();
    }
    let etap = refracted.w;
    return BsdfSample(refracted.xyz, vec3<f32>(1.0 / (etap * etap)), 1.0 - r, true, true);
}

// Walter's generalized half vector, turned to +z, in xyz and eta_i / eta_o in w; w = 0 when it
// is degenerate or seen from behind.
fn dielectric_half_vector(ior: f32, wo: vec3<f32>, wi: vec3<f32>) -> vec4<f32> {
    var etap = 1.0;
    if !same_side(wo, wi) {
        etap = select(1.0 / ior, ior, wo.z > 0.0);
    }
    var m = normalize_or_zero(wi * etap + wo);
    if all(m == vec3<f32>(0.0)) {
        return vec4<f32>(0.0);
    }
    if m.z < 0.0 {
        m = -m;
    }
    if m.z == 0.0 || dot(wo, m) * wo.z <= 0.0 || dot(wi, m) * wi.z <= 0.0 {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(m, etap);
}

fn dielectric_eval(alpha: f32, ior: f32, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    let h = dielectric_half_vector(ior, wo, wi);
    if h.w == 0.0 {
        return 0.0;
    }
    let m = h.xyz;
    let etap = h.w;
    let rt = fresnel_dielectric_rt(dot(wo, m), ior);
    let g_cos = g2_over_cos(alpha, wo, wi);
    if etap == 1.0 {
        return 0.25 * rt.x * ggx_d(alpha, m) * g_cos;
    }
    let cos_im = dot(wi, m);
    let cos_om = dot(wo, m);
    let denom = etap * cos_im + cos_om;
    return rt.y * ggx_d(alpha, m) * g_cos * abs(cos_im * cos_om) / (denom * denom);
}

fn dielectric_pdf(alpha: f32, ior: f32, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    let h = dielectric_half_vector(ior, wo, wi);
    if h.w == 0.0 {
        return 0.0;
    }
    let m = h.xyz;
    let etap = h.w;
    let rt = fresnel_dielectric_rt(dot(wo, m), ior);
    let pdf_m = visible_normal_pdf(alpha, wo * signum_f(wo.z), m);
    if etap == 1.0 {
        return pdf_m / (4.0 * abs(dot(wo, m))) * rt.x;
    }
    let cos_im = dot(wi, m);
    let denom = etap * cos_im + dot(wo, m);
    return pdf_m * etap * etap * abs(cos_im) / (denom * denom) * rt.y;
}

fn rough_dielectric_sample(alpha: f32, ior: f32, wo: vec3<f32>, u: vec2<f32>, u_lobe: f32) -> BsdfSample {
    let m = sample_visible_normal(alpha, wo * signum_f(wo.z), u);
    let r = fresnel_dielectric_rt(dot(wo, m), ior).x;
    var wi: vec3<f32>;
    var radiance_scale = 1.0;
    if u_lobe < r {
        wi = reflect_about(wo, m);
        if !same_side(wo, wi) {
            return no_sample();
        }
    } else {
        let refracted = refract_dir(wo, m, ior);
        if refracted.w == 0.0 {
            return no_sample();
        }
        wi = refracted.xyz;
        if wi.z * wo.z >= 0.0 {
            return no_sample();
        }
        radiance_scale = 1.0 / (refracted.w * refracted.w);
    }
    let pdf = dielectric_pdf(alpha, ior, wo, wi);
    if pdf <= 0.0 {
        return no_sample();
    }
    return BsdfSample(wi, vec3<f32>(g2_over_g1(alpha, wo, wi) * radiance_scale), pdf, false, true);
}

// ---- Coated (Bsdf::Coated): one GGX lobe with Schlick F0 = mix(coat F0, base, metallic), and
// (1 - metallic) base / (1 - F_avg) under the coat's (1 - F(cos o)) (1 - F(cos i)).

struct Coated {
    // The specular lobe as a Schlick conductor: albedo = its F0, alpha clamped to SMOOTH_ALPHA.
    specular: GpuMaterial,
    coat_f0: f32,
    diffuse: vec3<f32>,
}

fn schlick(f0: f32, cos_theta: f32) -> f32 {
    let x = 1.0 - clamp(cos_theta, 0.0, 1.0);
    let x2 = x * x;
    return f0 + (1.0 - f0) * (x2 * x2 * x);
}

fn coated_new(mat: GpuMaterial) -> Coated {
    let r = (mat.ior - 1.0) / (mat.ior + 1.0);
    let coat_f0 = r * r;
    let coat_average = coat_f0 + (1.0 - coat_f0) / 21.0;
    let metallic = mat.k.x;
    var specular = mat;
    specular.kind = MAT_CONDUCTOR;
    specular.flags = 0u;
    specular.alpha = max(mat.alpha, SMOOTH_ALPHA);
    specular.albedo = mix(vec3<f32>(coat_f0), mat.albedo, metallic);
    return Coated(specular, coat_f0, (1.0 - metallic) * mat.albedo / (1.0 - coat_average));
}

fn coated_diffuse_eval(c: Coated, wo: vec3<f32>, wi: vec3<f32>) -> vec3<f32> {
    if !same_side(wo, wi) {
        return vec3<f32>(0.0);
    }
    let through = (1.0 - schlick(c.coat_f0, abs(wo.z))) * (1.0 - schlick(c.coat_f0, abs(wi.z)));
    return c.diffuse * (through * FRAC_1_PI);
}

fn coated_specular_probability(c: Coated, wo: vec3<f32>) -> f32 {
    let fs = conductor_fresnel(c.specular, abs(wo.z));
    let specular = fs.x + fs.y + fs.z;
    let diffuse = (c.diffuse.x + c.diffuse.y + c.diffuse.z) * (1.0 - schlick(c.coat_f0, abs(wo.z)));
    if specular + diffuse > 0.0 {
        return specular / (specular + diffuse);
    }
    return 1.0;
}

fn coated_eval(c: Coated, wo: vec3<f32>, wi: vec3<f32>) -> vec3<f32> {
    return conductor_eval(c.specular, wo, wi) + coated_diffuse_eval(c, wo, wi);
}

fn coated_pdf(c: Coated, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    if !same_side(wo, wi) {
        return 0.0;
    }
    let p = coated_specular_probability(c, wo);
    return p * conductor_pdf(c.specular.alpha, wo, wi) + (1.0 - p) * abs(wi.z) * FRAC_1_PI;
}

fn coated_sample(c: Coated, wo: vec3<f32>, u: vec2<f32>, u_lobe: f32) -> BsdfSample {
    var s: BsdfSample;
    if u_lobe < coated_specular_probability(c, wo) {
        s = conductor_sample(c.specular, wo, u);
    } else {
        s = diffuse_sample(vec3<f32>(1.0), wo, u);
    }
    if !s.ok {
        return no_sample();
    }
    let wi = s.wi;
    let pdf = coated_pdf(c, wo, wi);
    if pdf <= 0.0 {
        return no_sample();
    }
    return BsdfSample(wi, coated_eval(c, wo, wi) * (abs(wi.z) / pdf), pdf, false, true);
}

// Bsdf::eval: f(wo, wi) without the cosine.
fn bsdf_eval(mat: GpuMaterial, wo: vec3<f32>, wi: vec3<f32>) -> vec3<f32> {
    if mat_is_delta(mat) || wo.z == 0.0 || wi.z == 0.0 {
        return vec3<f32>(0.0);
    }
    if mat.kind == MAT_DIFFUSE {
        return select(vec3<f32>(0.0), mat.albedo * FRAC_1_PI, same_side(wo, wi));
    }
    if HAS_CONDUCTOR && mat.kind == MAT_CONDUCTOR {
        return conductor_eval(mat, wo, wi);
    }
    if HAS_DIELECTRIC && mat.kind == MAT_DIELECTRIC {
        return vec3<f32>(dielectric_eval(mat.alpha, mat.ior, wo, wi));
    }
    if HAS_COATED && mat.kind == MAT_COATED {
        return coated_eval(coated_new(mat), wo, wi);
    }
    return vec3<f32>(0.0);
}

// Bsdf::pdf: the solid-angle density of bsdf_sample returning wi.
fn bsdf_pdf(mat: GpuMaterial, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    if mat_is_delta(mat) || wo.z == 0.0 || wi.z == 0.0 {
        return 0.0;
    }
    if mat.kind == MAT_DIFFUSE {
        return select(0.0, abs(wi.z) * FRAC_1_PI, same_side(wo, wi));
    }
    if HAS_CONDUCTOR && mat.kind == MAT_CONDUCTOR {
        return conductor_pdf(mat.alpha, wo, wi);
    }
    if HAS_DIELECTRIC && mat.kind == MAT_DIELECTRIC {
        return dielectric_pdf(mat.alpha, mat.ior, wo, wi);
    }
    if HAS_COATED && mat.kind == MAT_COATED {
        return coated_pdf(coated_new(mat), wo, wi);
    }
    return 0.0;
}

// Bsdf::sample.
fn bsdf_sample(mat: GpuMaterial, wo: vec3<f32>, u: vec2<f32>, u_lobe: f32) -> BsdfSample {
    if wo.z == 0.0 {
        return no_sample();
    }
    if mat.kind == MAT_DIFFUSE {
        return diffuse_sample(mat.albedo, wo, u);
    }
    if HAS_CONDUCTOR && mat.kind == MAT_CONDUCTOR {
        if mat.alpha < SMOOTH_ALPHA {
            let wi = vec3<f32>(-wo.x, -wo.y, wo.z);
            return BsdfSample(wi, conductor_fresnel(mat, abs(wo.z)), 1.0, true, true);
        }
        return conductor_sample(mat, wo, u);
    }
    if HAS_DIELECTRIC && mat.kind == MAT_DIELECTRIC {
        if mat_is_delta(mat) {
            return smooth_dielectric_sample(mat.ior, wo, u_lobe);
        }
        return rough_dielectric_sample(mat.alpha, mat.ior, wo, u, u_lobe);
    }
    if HAS_COATED && mat.kind == MAT_COATED {
        return coated_sample(coated_new(mat), wo, u, u_lobe);
    }
    return no_sample();
}
