// Blend of the two reference-view passes into the final image. Mirrors crate::cpu::blend.

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

// Blend of the two view passes: weighted by w_i where covered; where the weighted views are
// all holes, any covered view fills (never black where something exists).
struct Blend {
    weights: vec4<f32>,  // w0, w1, number of views, unused
};
@group(0) @binding(0) var<uniform> blend: Blend;
@group(0) @binding(1) var view0: texture_2d<f32>;
@group(0) @binding(2) var view1: texture_2d<f32>;

@fragment
fn fs_blend(in: FullOut) -> @location(0) vec4<f32> {
    let p = vec2<i32>(in.pos.xy);
    let a = textureLoad(view0, p, 0);
    var b = vec4<f32>(0.0);
    if blend.weights.z > 1.5 {
        b = textureLoad(view1, p, 0);
    }
    let wa = blend.weights.x * a.a;
    let wb = blend.weights.y * b.a;
    if wa + wb > 0.0 {
        return vec4<f32>((a.rgb * wa + b.rgb * wb) / (wa + wb), 1.0);
    }
    if a.a + b.a > 0.0 {
        return vec4<f32>((a.rgb * a.a + b.rgb * b.a) / (a.a + b.a), 1.0);
    }
    return vec4<f32>(0.0);
}
