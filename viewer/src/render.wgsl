// Reference-view passes (background + slab tile meshes) and the blend of two views.
// Mirrors crate::cpu; keep the two in step.

// Alpha of a view pass: 0 = hole, else the distance from the camera (metres); the sky is
// farther than anything (f16 keeps values up to 65504).
const SKY_DISTANCE: f32 = 60000.0;

struct View {
    clip_from_cam: mat4x4<f32>,
    origin_rel: vec4<f32>,   // ref - camera (xyz), w = face size
    ray_right: vec4<f32>,
    ray_up: vec4<f32>,
    ray_forward: vec4<f32>,
    params: vec4<f32>,       // frame lod, width, height, mip levels
};

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var layers: texture_2d_array<f32>;
@group(0) @binding(2) var samp: sampler;
// Per tile: x = face | layer << 8, y = min level.
@group(0) @binding(3) var<storage, read> tile_info: array<vec2<u32>>;

fn face_forward(f: u32) -> vec3<f32> {
    switch f {
        case 0u: { return vec3<f32>(1.0, 0.0, 0.0); }
        case 1u: { return vec3<f32>(-1.0, 0.0, 0.0); }
        case 2u: { return vec3<f32>(0.0, 1.0, 0.0); }
        case 3u: { return vec3<f32>(0.0, -1.0, 0.0); }
        case 4u: { return vec3<f32>(0.0, 0.0, 1.0); }
        default: { return vec3<f32>(0.0, 0.0, -1.0); }
    }
}

fn face_up(f: u32) -> vec3<f32> {
    switch f {
        case 2u: { return vec3<f32>(0.0, 0.0, 1.0); }
        case 3u: { return vec3<f32>(0.0, 0.0, -1.0); }
        default: { return vec3<f32>(0.0, 1.0, 0.0); }
    }
}

fn face_right(f: u32) -> vec3<f32> {
    return cross(face_forward(f), face_up(f));
}

// Face holding a direction: major axis, ties x before y before z (FaceCoord::from_dir).
fn face_of(d: vec3<f32>) -> u32 {
    let a = abs(d);
    if a.x >= a.y && a.x >= a.z {
        return select(1u, 0u, d.x > 0.0);
    }
    if a.y >= a.z {
        return select(3u, 2u, d.y > 0.0);
    }
    return select(5u, 4u, d.z > 0.0);
}

// Level-0 face-pixel position of a direction on face f.
fn pixel_on_face(f: u32, d: vec3<f32>) -> vec2<f32> {
    let n = view.origin_rel.w;
    let z = dot(d, face_forward(f));
    let u = dot(d, face_right(f)) / z;
    let v = dot(d, face_up(f)) / z;
    return vec2<f32>((u + 1.0) * 0.5 * n, (1.0 - v) * 0.5 * n);
}

fn sample_level(layer: u32, f: u32, pix: vec2<f32>, level: f32) -> vec4<f32> {
    let n = view.origin_rel.w;
    let nl = max(floor(n / exp2(level)), 1.0);
    let p = clamp(pix * (nl / n), vec2<f32>(0.5), vec2<f32>(nl - 0.5));
    let uv = vec2<f32>(p.x / nl, (f32(f) * nl + p.y) / (6.0 * nl));
    return textureSampleLevel(layers, samp, uv, layer, level);
}

// Trilinear from two explicit levels, each clamped inside its own face.
fn sample_face(layer: u32, f: u32, pix: vec2<f32>, lod_in: f32) -> vec4<f32> {
    let lod = clamp(lod_in, 0.0, view.params.w - 1.0);
    let l0 = floor(lod);
    let t = lod - l0;
    let a = sample_level(layer, f, pix, l0);
    if t == 0.0 {
        return a;
    }
    let b = sample_level(layer, f, pix, l0 + 1.0);
    return mix(a, b, t);
}

struct FullOut {
    @builtin(position) pos: vec4<f32>,
};

@vertex
fn vs_full(@builtin(vertex_index) i: u32) -> FullOut {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    var out: FullOut;
    out.pos = vec4<f32>(x, y, 0.0, 1.0);
    return out;
}

// A view pass writes colour (alpha = distance, 0 = hole) and the drawn tile (index + 1,
// 0 = none) for the visibility feedback.
struct PassOut {
    @location(0) color: vec4<f32>,
    @location(1) tile: u32,
};

// Background layer (sky), drawn after the meshes where none drew.
@fragment
fn fs_background(in: FullOut) -> PassOut {
    let ndc = vec2<f32>(in.pos.x / view.params.y * 2.0 - 1.0, 1.0 - in.pos.y / view.params.z * 2.0);
    let d = view.ray_forward.xyz + ndc.x * view.ray_right.xyz + ndc.y * view.ray_up.xyz;
    let f = face_of(d);
    let c = sample_face(0u, f, pixel_on_face(f, d), view.params.x);
    // Any sky in the footprint: the meshes drawn over it use the 0.5 mask threshold, and the
    // two complementary masks must not both fail at a sky silhouette.
    if c.a <= 0.0 {
        discard;
    }
    var out: PassOut;
    out.color = vec4<f32>(c.rgb, SKY_DISTANCE);
    out.tile = 0u;
    return out;
}

// The plain panorama (one cube map, no slabs, no blending): the baseline an ordinary
// panorama viewer draws.
@fragment
fn fs_panorama(in: FullOut) -> @location(0) vec4<f32> {
    let ndc = vec2<f32>(in.pos.x / view.params.y * 2.0 - 1.0, 1.0 - in.pos.y / view.params.z * 2.0);
    let d = view.ray_forward.xyz + ndc.x * view.ray_right.xyz + ndc.y * view.ray_up.xyz;
    let f = face_of(d);
    let c = sample_face(0u, f, pixel_on_face(f, d), view.params.x);
    return vec4<f32>(c.rgb, 1.0);
}

struct MeshIn {
    @location(0) pos_in_face: vec2<f32>,
    @location(1) depth_m: f32,
    @location(2) packed: u32,   // tile << 3 | face
};

struct MeshOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) pos_from_ref: vec3<f32>,
    @location(1) @interpolate(flat) tile: u32,
};

@vertex
fn vs_mesh(v: MeshIn) -> MeshOut {
    let n = view.origin_rel.w;
    let f = v.packed & 7u;
    let u = 2.0 * v.pos_in_face.x / n - 1.0;
    let w = 1.0 - 2.0 * v.pos_in_face.y / n;
    let d = normalize(face_forward(f) + u * face_right(f) + w * face_up(f)) * v.depth_m;
    var out: MeshOut;
    out.pos = view.clip_from_cam * vec4<f32>(d + view.origin_rel.xyz, 1.0);
    out.pos_from_ref = d;
    out.tile = v.packed >> 3u;
    return out;
}

// Projective texturing from the reference viewpoint: exact at the reference sample whatever
// the mesh depth; the opacity mask cuts the slab.
@fragment
fn fs_mesh(in: MeshOut) -> PassOut {
    let info = tile_info[in.tile];
    let f = info.x & 7u;
    let layer = info.x >> 8u;
    let lod = max(view.params.x, f32(info.y));
    let c = sample_face(layer, f, pixel_on_face(f, in.pos_from_ref), lod);
    // Masks are cut at 0.5. From level 1 on, deeper slabs cut at 0.25: where two slabs'
    // filtered masks meet (they sum to about 1) one of them then always draws, so coarse
    // levels open no crack at slab boundaries; deeper slabs lie behind, so the depth test
    // hides what they overhang. Level 0 stays exact.
    if c.a < select(0.25, 0.5, layer == 1u || lod < 1.0) {
        discard;
    }
    let dist = clamp(length(in.pos_from_ref + view.origin_rel.xyz), 1e-3, SKY_DISTANCE);
    var out: PassOut;
    out.color = vec4<f32>(c.rgb, dist);
    out.tile = in.tile + 1u;
    return out;
}

