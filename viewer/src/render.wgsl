// Reference-view pass (slab tile meshes) and the plain panorama; prepended with cube.wgsl.
// Mirrors crate::cpu; keep the two in step.

// Scale of the reversed-Z depth of the tile meshes: 1, or > 1 for the second view when it is
// drawn against the first view's depth (a fragment then survives unless it lies more than
// `depth_scale` times farther than the first view's surface, where the blend would give it
// a weight below exp(-SHARPNESS (depth_scale - 1))).
override depth_scale: f32 = 1.0;
// Reversed-Z depth the first view's sky writes in that mode: behind every mesh (10 km is
// 1e-6), in front of the clear value 0.
const SKY_DEPTH: f32 = 1e-20;

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var layers: texture_2d_array<f32>;
@group(0) @binding(2) var samp: sampler;
// Per tile: x = face | layer << 8, y = min level, z = highlight (f32 bits), w = slab.
@group(0) @binding(3) var<storage, read> tile_info: array<vec4<u32>>;

// The plain panorama (one cube map, no slabs, no blending): the baseline an ordinary
// panorama viewer draws.
@fragment
fn fs_panorama(in: FullOut) -> @location(0) vec4<f32> {
    let d = pixel_ray(view.ray_right.xyz, view.ray_up.xyz, view.ray_forward.xyz, view.params.yz, in.pos.xy);
    let f = face_of(d);
    let n = view.origin_rel.w;
    let c = sample_face(layers, samp, n, view.params.w, 0u, f, pixel_on_face(f, d, n), view.params.x);
    return vec4<f32>(c.rgb, 1.0);
}

// Colour and the drawn tile (index + 1, 0 = none) for the visibility feedback and overlays.
struct PassOut {
    @location(0) color: vec4<f32>,
    @location(1) tile: u32,
};

// Background layer (sky), drawn after the meshes where none drew; alpha 0 (hole) where the
// background has no sky either. No `discard`: the depth test alone decides, before shading.
fn background_color(pos: vec2<f32>) -> vec4<f32> {
    let d = pixel_ray(view.ray_right.xyz, view.ray_up.xyz, view.ray_forward.xyz, view.params.yz, pos);
    let f = face_of(d);
    let n = view.origin_rel.w;
    let c = sample_face(layers, samp, n, view.params.w, 0u, f, pixel_on_face(f, d, n), view.params.x);
    return select(vec4<f32>(0.0), vec4<f32>(c.rgb, SKY_DISTANCE), c.a > 0.0);
}

@fragment
fn fs_background(in: FullOut) -> @location(0) vec4<f32> {
    return background_color(in.pos.xy);
}

// The first view's sky when the second view is drawn against its depth: at SKY_DEPTH, and
// only where there is sky (a hole leaves depth 0, so the second view fills it).
@vertex
fn vs_sky_depth(@builtin(vertex_index) i: u32) -> FullOut {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    var out: FullOut;
    out.pos = vec4<f32>(x, y, SKY_DEPTH, 1.0);
    return out;
}

@fragment
fn fs_background_sky_depth(in: FullOut) -> @location(0) vec4<f32> {
    let c = background_color(in.pos.xy);
    if c.a == 0.0 {
        discard;
    }
    return c;
}

@fragment
fn fs_background_ids(in: FullOut) -> PassOut {
    var out: PassOut;
    out.color = background_color(in.pos.xy);
    out.tile = 0u;
    return out;
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
    out.pos.z = out.pos.z * depth_scale;
    out.pos_from_ref = d;
    out.tile = v.packed >> 3u;
    return out;
}

// Projective texturing from the reference viewpoint: exact at the reference sample whatever
// the mesh depth; the opacity mask cuts the slab. Alpha out = distance to the camera.
fn mesh_color(in: MeshOut) -> vec4<f32> {
    let info = tile_info[in.tile];
    let f = info.x & 7u;
    let layer = info.x >> 8u;
    let lod = max(view.params.x, f32(info.y));
    let n = view.origin_rel.w;
    let pix = pixel_on_face(f, in.pos_from_ref, n);
    var c: vec4<f32>;
    if fract(view.params.x) == 0.0 {
        // A whole frame level (and whole tile levels): one lookup. The condition is uniform,
        // so SIMD rasterisers (llvmpipe runs both sides of per-pixel branches) skip the
        // two-level path for the whole draw.
        c = sample_level(layers, samp, n, layer, f, pix, min(lod, view.params.w - 1.0));
    } else {
        c = sample_face(layers, samp, n, view.params.w, layer, f, pix, lod);
    }
    // Masks are cut at 0.5. From level 1 on, deeper slabs cut at 0.25: where two slabs'
    // filtered masks meet (they sum to about 1) one of them then always draws, so coarse
    // levels open no crack at slab boundaries; deeper slabs lie behind, so the depth test
    // hides what they overhang. Level 0 stays exact.
    if c.a < select(0.25, 0.5, layer == 1u || lod < 1.0) {
        discard;
    }
    let dist = clamp(length(in.pos_from_ref + view.origin_rel.xyz), 1e-3, SKY_DISTANCE);
    return vec4<f32>(c.rgb, dist);
}

// Colour only (frames without tile-visibility feedback or overlays).
@fragment
fn fs_mesh(in: MeshOut) -> @location(0) vec4<f32> {
    return mesh_color(in);
}

@fragment
fn fs_mesh_ids(in: MeshOut) -> PassOut {
    var out: PassOut;
    out.color = mesh_color(in);
    out.tile = in.tile + 1u;
    return out;
}
