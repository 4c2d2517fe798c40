// Tile-visibility feedback (Goss & Yuasa §3): count the visible pixels of every tile of a
// view pass from its tile-id target. Mirrors crate::cpu's tile counts.

@group(0) @binding(0) var ids: texture_2d<u32>;
@group(0) @binding(1) var<storage, read_write> counts: array<atomic<u32>>;

@compute @workgroup_size(8, 8)
fn count(@builtin(global_invocation_id) id: vec3<u32>) {
    let dims = textureDimensions(ids);
    if id.x >= dims.x || id.y >= dims.y {
        return;
    }
    let t = textureLoad(ids, vec2<i32>(id.xy), 0).x;
    if t > 0u && t <= arrayLength(&counts) {
        atomicAdd(&counts[t - 1u], 1u);
    }
}
