// Reference-view pass (slab tile meshes) and the plain panorama; prepended with cube.wgsl.
// Mirrors crate::cpu; keep the two in step.

// Scale of the reversed-Z depth of the tile meshes: 1, or > 1 for the second view when it is
// drawn against the first view's depth (a fragment then survives unless it lies more than
// `depth_scale` times farther than the first view's surface, where the blend would give it
// a weight below exp(-SHARPNESS (depth_scale - 1))).
override depth_scale: f32 = 1.0;
// Reversed-Z depth the first view's sky writes in that mode: behind every mesh nearer than
// NEAR_M / SKY_DEPTH = 42 km (10 km is 1e-6), in front of the clear value 0. 2^-22, not
// smaller: wgpu's GL backend maps depth z to 2z - 1 in the vertex shader and GL maps it back,
// which rounds anything below 2^-25 to the clear value.
const SKY_DEPTH: f32 = 2.384185791015625e-7;

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var layers: texture_2d_array<f32>;
@group(0) @binding(2) var samp: sampler;
// Per tile (`tile_texel`): x = face | layer << 8, y = min level, z = highlight (f32 bits),
// w = slab.
@group(0) @binding(3) var tile_info: texture_2d<u32>;

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

// Background layer (sky) of view `v`, drawn after the meshes where none drew: alpha
// SKY_DISTANCE where the view sees sky itself, else 0 (a hole; the sky behind the view's
// occluders is for the fill pass alone, `fs_fill`). No `discard`: the depth test alone
// decides, before shading.
fn background_of(v: View, tex: texture_2d_array<f32>, s: sampler, pos: vec2<f32>) -> vec4<f32> {
    let d = pixel_ray(v.ray_right.xyz, v.ray_up.xyz, v.ray_forward.xyz, v.params.yz, pos);
    let f = face_of(d);
    let n = v.origin_rel.w;
    let c = sample_face(tex, s, n, v.params.w, 0u, f, pixel_on_face(f, d, n), v.params.x);
    return select(vec4<f32>(0.0), vec4<f32>(c.rgb, SKY_DISTANCE), c.a > SEEN_SKY);
}

fn background_color(pos: vec2<f32>) -> vec4<f32> {
    return background_of(view, layers, samp, pos);
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

// refview::stretch: the flag of a stretched triangle's vertices and how much farther it counts.
const STRETCHED_BIT: u32 = 0x80000000u;
const STRETCH_PUSH: f32 = 2.0;

struct MeshIn {
    @location(0) pos_in_face: vec2<f32>,
    @location(1) depth_m: f32,
    @location(2) packed: u32,   // tile << 3 | face
};

// Everything per tile (face, layer, level) is looked up per vertex and passed flat, and the
// point is passed in the reference face's own basis, so the fragment shader needs neither
// the tile-info buffer nor the per-face switches (software rasterisers shade every fragment
// of a SIMD block through both).
struct MeshOut {
    @builtin(position) pos: vec4<f32>,
    // Point relative to the camera (its length is the distance).
    @location(0) cam_rel: vec3<f32>,
    // Point relative to the reference viewpoint in its face's basis (right, up, forward):
    // the face pixel is a projective function of it, exact per fragment.
    @location(1) ref_rufw: vec3<f32>,
    // Per tile, in one flat slot (a software rasteriser sets up every output slot of every
    // triangle): the tile, face | layer << 8, the level of detail (clamped to the chain) and
    // the face margin at it (`face_margin`), the last two as f32 bits.
    @location(2) @interpolate(flat) per_tile: vec4<u32>,
};

@vertex
fn vs_mesh(v: MeshIn) -> MeshOut {
    let n = view.origin_rel.w;
    let f = v.packed & 7u;
    let u = 2.0 * v.pos_in_face.x / n - 1.0;
    let w = 1.0 - 2.0 * v.pos_in_face.y / n;
    let scale = v.depth_m / length(vec3<f32>(u, w, 1.0));
    let d = (face_forward(f) + u * face_right(f) + w * face_up(f)) * scale;
    let tile = (v.packed >> 3u) & 0x0fffffffu;
    let info = textureLoad(tile_info, tile_texel(tile), 0);
    // A stretched triangle (refview::stretch) counts STRETCH_PUSH times farther, in the
    // depth test (reversed Z: z / STRETCH_PUSH) and in the blend (its distance).
    let push = select(1.0, STRETCH_PUSH, (v.packed & STRETCHED_BIT) != 0u);
    var out: MeshOut;
    out.pos = view.clip_from_cam * vec4<f32>(d + view.origin_rel.xyz, 1.0);
    out.pos.z = out.pos.z * depth_scale / push;
    out.cam_rel = (d + view.origin_rel.xyz) * push;
    out.ref_rufw = vec3<f32>(u, w, 1.0) * scale;
    let level = clamp(max(view.params.x, f32(info.y)), 0.0, view.params.w - 1.0);
    out.per_tile = vec4<u32>(tile, info.x, bitcast<u32>(level), bitcast<u32>(face_margin(n, level)));
    return out;
}

// Projective texturing from the reference viewpoint: exact at the reference sample whatever
// the mesh depth; the opacity mask cuts the slab. Alpha out = distance to the camera.
fn mesh_color(in: MeshOut) -> vec4<f32> {
    let f = in.per_tile.y & 7u;
    let layer = in.per_tile.y >> 8u;
    let lod = bitcast<f32>(in.per_tile.z);
    let q = in.ref_rufw.xy / in.ref_rufw.z;
    let uv = face_uv(f, vec2<f32>(q.x + 1.0, 1.0 - q.y) * 0.5, bitcast<f32>(in.per_tile.w));
    let c = textureSampleLevel(layers, samp, uv, layer, lod);
    // Masks are cut at 0.5. From level 1 on, deeper slabs cut at 0.45: where two slabs'
    // filtered masks meet (they sum to about 1) one of them then always draws, so coarse
    // levels open no crack at slab boundaries, while a slab's blurred edge reaches hardly
    // past its outline (meshes overhang the outline by up to two texels, `slabs::mesh`, and
    // a lower cut let a slab's coarse edge cover the deeper slab beside it). Level 0 stays
    // exact.
    if c.a < select(0.45, 0.5, layer == 1u || lod < 1.0) {
        discard;
    }
    let dist = clamp(length(in.cam_rel), 1e-3, SKY_DISTANCE);
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
    out.tile = in.per_tile.x + 1u;
    return out;
}

// Tile ids only (feedback frames, drawn beside the picture, usually at reduced resolution):
// depth + id, no colour. The opacity mask still decides (one lookup), so the ids are those of
// the view pass; the sky writes nothing (the cleared 0 = no tile).
@fragment
fn fs_mesh_id_only(in: MeshOut) -> @location(0) u32 {
    _ = mesh_color(in);
    return in.per_tile.x + 1u;
}

// Fused frames (no tile ids, no overlays): no view targets and no composite pass. The first
// view draws straight into the output (sRGB colour, alpha 1) and its depth; the second view
// is then drawn against that depth (scaled by `depth_scale`, as above) with hardware
// blending, each of its fragments weighted by the share the composite would give it,
// computed from the first view's distance there: out = β c_b + (1 − β) c_a with
// β = w_b / (w_a + w_b) (composite.wgsl's `blend_at`). The distance comes from a copy of the
// first view's depth: with reversed Z, NDC depth is NEAR / z, so along one pixel's ray
// d_a = d_b · z_b / z_a (no distance target: a second colour target costs a software
// rasteriser a conversion and a write per pixel).

struct Blend {
    weights: vec4<f32>,  // w0, w1, number of views, unused
    flags: vec4<u32>,
};
@group(1) @binding(0) var<uniform> blend: Blend;
// The half-resolution second view (colour, alpha = distance; `blend_half`).
@group(1) @binding(1) var half_second: texture_2d<f32>;
// A copy of the first view's depth (`first_distance`), read as a plain float texture (GLSL
// has no texel loads from depth textures).
@group(1) @binding(2) var first_depth: texture_2d<f32>;

// Devices without depth copies (`Caps::depth_copy`; GL): the first view draws into the
// depth texture bound here, and this full-screen pass, first in the second view's pass,
// writes it into the depth the second view is drawn against (compare always).
struct DepthOut {
    @builtin(frag_depth) depth: f32,
};

@fragment
fn fs_copy_depth(in: FullOut) -> DepthOut {
    var out: DepthOut;
    out.depth = textureLoad(first_depth, vec2<i32>(in.pos.xy), 0).x;
    return out;
}

// The first view's meshes (and a one-view frame's sky below): the output alone.
@fragment
fn fs_mesh_first(in: MeshOut) -> @location(0) vec4<f32> {
    return vec4<f32>(mesh_color(in).rgb, 1.0);
}

// The sky of a one-view frame where its meshes left the pixel empty (depth test, no depth
// test, so the rasteriser skips covered blocks before shading), writing SKY_DEPTH
// (`vs_sky_depth`) where there is sky so that the fill's depth test passes holes alone; a
// hole keeps alpha 0 and depth 0.
@fragment
fn fs_sky_first(in: FullOut) -> @location(0) vec4<f32> {
    let c = background_color(in.pos.xy);
    if c.a == 0.0 {
        discard;
    }
    return vec4<f32>(c.rgb, 1.0);
}

// The first view's distance along the ray of the second view's fragment `in`, whose own
// distance is `db`; 0 where the first view drew no mesh (cleared depth).
fn first_distance(in: MeshOut, db: f32) -> f32 {
    let za = textureLoad(first_depth, vec2<i32>(in.pos.xy), 0).x;
    let zb = in.pos.z / depth_scale;
    return select(0.0, clamp(db * zb / za, 1e-3, SKY_DISTANCE), za > 0.0);
}

// Share β of the second view at a pixel where the first view's distance is `da` (0 = hole)
// and the second view's is `db`.
fn second_share(da: f32, db: f32) -> f32 {
    let ca = select(0.0, 1.0, da > 0.0);
    let dmin = select(db, min(da, db), da > 0.0);
    let na = ca * exp(max(-80.0, -SHARPNESS * (da / dmin - 1.0)));
    let nb = exp(max(-80.0, -SHARPNESS * (db / dmin - 1.0)));
    var wa = blend.weights.x * na;
    var wb = blend.weights.y * nb;
    if wa + wb <= 0.0 {
        wa = ca;
        wb = 1.0;
    }
    return wb / (wa + wb);
}

// The share depends on the ratio of the two distances only, and along one ray
// d_a / d_b = z_b / z_a: no distance is computed (nor the point relative to the camera
// interpolated) for the second view's fragments.
@fragment
fn fs_mesh_second(in: MeshOut) -> @location(0) vec4<f32> {
    let c = mesh_color(in);
    let za = textureLoad(first_depth, vec2<i32>(in.pos.xy), 0).x;
    let ratio = select(0.0, in.pos.z / depth_scale / za, za > 0.0);
    return vec4<f32>(c.rgb, second_share(ratio, 1.0));
}

// The second view's meshes at a sample (weight 0; drawn only where nearer than the first
// view's meshes): where the first view drew no mesh, its sky (looked up in the first view,
// group 2) counts as a surface at SKY_DISTANCE, so the second view fills only the first
// view's holes, as in the composite. (With any weight above 0 the blend gives a mesh almost
// everything against the sky, as `fs_mesh_second` does where the first view's distance is 0.)
@fragment
fn fs_mesh_second_at_sample(in: MeshOut) -> @location(0) vec4<f32> {
    let c = mesh_color(in);
    let da = first_distance(in, c.a);
    let sky = background_of(other_view, other_layers, other_samp, in.pos.xy).a;
    let share = second_share(select(da, sky, da == 0.0), c.a);
    // No share (weight 0): no depth either, so the first view's sky is still drawn there.
    if share == 0.0 {
        discard;
    }
    return vec4<f32>(c.rgb, share);
}

// The other view of a two-view pass (group 2): the first view for the second view's meshes
// at a sample (`fs_mesh_second_at_sample`), the second view for the sky (`fs_sky_other`).
@group(2) @binding(0) var<uniform> other_view: View;
@group(2) @binding(1) var other_layers: texture_2d_array<f32>;
@group(2) @binding(2) var other_samp: sampler;

// The sky of a two-view frame, drawn last where neither view's meshes drew, in two parts.
// The sky lies at infinity: both reference views see the same sky in every direction where
// both see sky, so one lookup in the heavier view stands for the blend of two. First part
// (group 0 = the heavier view): its sky, writing SKY_DEPTH (`vs_sky_depth`) where it has
// sky; the depth test against the cleared depth skips covered blocks before shading (the
// `discard` only delays the depth write).
@fragment
fn fs_sky_heavier(in: FullOut) -> @location(0) vec4<f32> {
    let c = background_color(in.pos.xy);
    if c.a == 0.0 {
        discard;
    }
    return vec4<f32>(c.rgb, 1.0);
}

// Second part: the other view's sky (group 2) where the heavier view's sky has a hole and no
// mesh drew (depth still cleared); a hole (alpha 0) where neither view has sky.
@fragment
fn fs_sky_other(in: FullOut) -> @location(0) vec4<f32> {
    let c = background_of(other_view, other_layers, other_samp, in.pos.xy);
    return select(vec4<f32>(0.0), vec4<f32>(c.rgb, 1.0), c.a > 0.0);
}

// Half-resolution second view (DrawBudget::half_res_second): the second view is drawn first,
// at half the width and height, into an Rgba16Float target (alpha = distance, 0 = hole) bound
// as `half_second`; the first view then draws every pixel (meshes, then its background where
// no mesh drew, holes included) and blends in the second view's nearest texel as the
// composite would.
fn blend_half(pos: vec2<f32>, a: vec4<f32>) -> vec4<f32> {
    let size = vec2<i32>(textureDimensions(half_second));
    let b = textureLoad(half_second, min(vec2<i32>(pos * 0.5), size - vec2<i32>(1)), 0);
    let ca = select(0.0, 1.0, a.a > 0.0);
    let cb = select(0.0, 1.0, b.a > 0.0);
    if ca + cb == 0.0 {
        return vec4<f32>(0.0);
    }
    var dmin = max(a.a, b.a);
    if ca > 0.0 { dmin = min(dmin, a.a); }
    if cb > 0.0 { dmin = min(dmin, b.a); }
    let na = ca * exp(max(-80.0, -SHARPNESS * (a.a / dmin - 1.0)));
    let nb = cb * exp(max(-80.0, -SHARPNESS * (b.a / dmin - 1.0)));
    var wa = blend.weights.x * na;
    var wb = blend.weights.y * nb;
    if wa + wb <= 0.0 {
        wa = ca;
        wb = cb;
    }
    return vec4<f32>((a.rgb * wa + b.rgb * wb) / (wa + wb), 1.0);
}

@fragment
fn fs_mesh_over_half(in: MeshOut) -> @location(0) vec4<f32> {
    return blend_half(in.pos.xy, mesh_color(in));
}

@fragment
fn fs_background_over_half(in: FullOut) -> @location(0) vec4<f32> {
    // At SKY_DEPTH (`vs_sky_depth`) where anything is drawn, for the fill's depth test; a
    // hole keeps depth 0.
    let c = blend_half(in.pos.xy, background_color(in.pos.xy));
    if c.a == 0.0 {
        discard;
    }
    return c;
}

// The fill pass, last in a fused frame: a pixel that neither view covers (no mesh, and no
// sky that a reference sees there: the output's alpha is 0) takes the colour of the farther
// side. From the pixel, a covered pixel (output alpha above 0) is sought to the left,
// right, above and below, at FILL_STEPS up to 48 pixels; of those found the farthest wins
// (smallest reversed-Z depth; the sky, at SKY_DEPTH, or at the cleared 0 where the second
// part of a two-view sky wrote no depth, is the farthest).
// Where that is sky, or nothing is found, the pixel shows the complete sky of the heavier
// view (group 0) in its own direction, the sky behind the references' occluders (where the
// background has none there, the sky pixel found); else the colour of the pixel found. Filled pixels get alpha FILLED_ALPHA (eval counts them apart
// from covered ones); a pixel stays a hole (alpha 0) only where nothing is found and there
// is no sky. Group 1: `half_second` holds a copy of the output, `first_depth` the final
// depth of the frame (a copy of it where the device copies depth; the layout of the second
// view's group). Where it does, the frame's depth is attached read-only and tested equal to
// the cleared 0: covered pixels (all but the few of a two-view sky's second part) are
// skipped before shading, as software rasterisers skip whole blocks; elsewhere (GL) every
// pixel runs the shader and a covered one leaves at once.
// The offsets probed in each direction (every pixel near, then wider steps: the first
// covered pixel may lie up to a third past the nearest one).
const FILL_STEP_COUNT: i32 = 12;
const FILL_STEPS = array<i32, 12>(1, 2, 3, 4, 6, 8, 11, 16, 22, 30, 40, 48);
const FILLED_ALPHA: f32 = 128.0 / 255.0;

@fragment
fn fs_fill(in: FullOut) -> @location(0) vec4<f32> {
    let p = vec2<i32>(in.pos.xy);
    // Covered pixels start with every direction closed, so the search loop ends at once for
    // a block of them (software rasterisers run a loop while any lane of the block runs it,
    // discarded lanes included); they discard after it.
    let covered = textureLoad(half_second, p, 0).a > 0.0;
    let size = vec2<i32>(textureDimensions(first_depth));
    var dirs = array<vec2<i32>, 4>(vec2<i32>(1, 0), vec2<i32>(-1, 0), vec2<i32>(0, 1), vec2<i32>(0, -1));
    var reach = FILL_STEPS;
    var open = vec4<bool>(!covered);
    var best_z = 2.0;
    var best_p = vec2<i32>(-1, -1);
    for (var k = 0; k < FILL_STEP_COUNT; k++) {
        for (var d = 0; d < 4; d++) {
            if open[d] {
                let q = p + dirs[d] * reach[k];
                if any(q < vec2<i32>(0)) || any(q >= size) {
                    open[d] = false;
                } else if textureLoad(half_second, q, 0).a > 0.0 {
                    // Covered; depth 0 there is the other view's sky (no depth written).
                    open[d] = false;
                    let z = textureLoad(first_depth, q, 0).x;
                    if z < best_z {
                        best_z = z;
                        best_p = q;
                    }
                }
            }
        }
        if !any(open) {
            break;
        }
    }
    if covered {
        discard;
    }
    let sky = sample_face_dir(in.pos.xy);
    let has_sky = sky.a > 0.0;
    if best_p.x < 0 {
        return select(vec4<f32>(0.0), vec4<f32>(sky.rgb, FILLED_ALPHA), has_sky);
    }
    // The farther side is sky: the sky in the pixel's own direction where the background
    // has it, else the sky pixel found.
    let found = vec4<f32>(textureLoad(half_second, best_p, 0).rgb, FILLED_ALPHA);
    if best_z <= SKY_DEPTH * 1.5 && has_sky {
        return vec4<f32>(sky.rgb, FILLED_ALPHA);
    }
    return found;
}

// The background of the pass's view in the direction of pixel `pos`, alpha as stored.
fn sample_face_dir(pos: vec2<f32>) -> vec4<f32> {
    let d = pixel_ray(view.ray_right.xyz, view.ray_up.xyz, view.ray_forward.xyz, view.params.yz, pos);
    let f = face_of(d);
    let n = view.origin_rel.w;
    return sample_face(layers, samp, n, view.params.w, 0u, f, pixel_on_face(f, d, n), view.params.x);
}
