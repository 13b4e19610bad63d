// A C interface to Intel's Masked Occlusion Culling for the benches (Rust calls C, not C++ classes). Each
// function is one MOC call or a loop of them, so the time measured is MOC's own.
#include "CullingThreadpool.h"
#include "MaskedOcclusionCulling.h"

#include <algorithm>
#include <vector>

// One occluder: `triangles` triangles of object-space vertices (x, y, z as 3 packed floats, 3 per triangle,
// unindexed) and the column-major matrix from object to clip space.
struct CulletMocDraw {
    const float* vertices;
    unsigned triangles;
    float clip_from_object[16];
};

namespace {
// Occluders are counter-clockwise seen from outside: MOC culls the clockwise ones (its default).
const MaskedOcclusionCulling::BackfaceWinding kWinding = MaskedOcclusionCulling::BACKFACE_CW;
const MaskedOcclusionCulling::VertexLayout kLayout(12, 4, 8);
}  // namespace

extern "C" {

// A buffer, or null for a size MOC cannot take (it asserts a width that is a multiple of 8 and a height that is
// a multiple of 4).
MaskedOcclusionCulling* cullet_moc_new(unsigned width, unsigned height, float near_distance) {
    if (width == 0 || height == 0 || width % 8 != 0 || height % 4 != 0) return nullptr;
    MaskedOcclusionCulling* moc = MaskedOcclusionCulling::Create();
    moc->SetResolution(width, height);
    moc->SetNearClipPlane(near_distance);
    return moc;
}

void cullet_moc_free(MaskedOcclusionCulling* moc) { MaskedOcclusionCulling::Destroy(moc); }

// 0 SSE2, 1 SSE4.1, 2 AVX2, 3 AVX-512: the back end MOC picked for this CPU.
int cullet_moc_implementation(MaskedOcclusionCulling* moc) { return moc->GetImplementation(); }

// Clears the buffer and renders every draw on the calling thread. `indices` holds 0, 1, 2, ... for the largest
// draw.
void cullet_moc_render(MaskedOcclusionCulling* moc, const CulletMocDraw* draws, unsigned count,
                       const unsigned* indices) {
    moc->ClearBuffer();
    for (unsigned i = 0; i < count; i++) {
        moc->RenderTriangles(draws[i].vertices, indices, (int)draws[i].triangles, draws[i].clip_from_object,
                             kWinding, MaskedOcclusionCulling::CLIP_PLANE_ALL, kLayout);
    }
}

// Tests `count` rectangles (NDC x min, y min, x max, y max, then the nearest clip w: 5 floats each) and writes
// 1 to `visible` for those MOC keeps; returns how many it keeps. Reads the buffer only.
unsigned cullet_moc_test_rects(const MaskedOcclusionCulling* moc, const float* rects, unsigned count,
                               unsigned char* visible) {
    unsigned kept = 0;
    for (unsigned i = 0; i < count; i++) {
        const float* r = rects + 5 * i;
        const bool keep = moc->TestRect(r[0], r[1], r[2], r[3], r[4]) == MaskedOcclusionCulling::VISIBLE;
        visible[i] = keep;
        kept += keep;
    }
    return kept;
}

// MOC's own multithreaded rasterizer on a MOC buffer, with the calling thread's scratch for clip-space
// vertices.
struct CulletMocPool {
    CullingThreadpool pool;
    std::vector<float> clip;
    std::vector<unsigned> indices;
    CulletMocPool(unsigned threads, unsigned bins_wide, unsigned bins_high)
        : pool(threads, bins_wide, bins_high) {}
};

// `threads` workers, 4x4 bins (MOC's sample's setting) where the buffer has room, fewer on small buffers: a bin
// narrower than one of MOC's tiles (32 pixels wide, up to 16 high) would be empty, and MOC divides by its size.
// Null where that leaves fewer bins than threads (MOC asserts at least one a thread). The workers start
// suspended.
CulletMocPool* cullet_moc_pool_new(MaskedOcclusionCulling* moc, unsigned threads) {
    unsigned width = 0, height = 0;
    moc->GetResolution(width, height);
    const unsigned bins_wide = std::max(1u, std::min(4u, width / 32));
    const unsigned bins_high = std::max(1u, std::min(4u, height / 16));
    if (bins_wide * bins_high < threads) return nullptr;
    CulletMocPool* pool = new CulletMocPool(threads, bins_wide, bins_high);
    pool->pool.SetBuffer(moc);
    return pool;
}

void cullet_moc_pool_free(CulletMocPool* pool) { delete pool; }

// Transforms every draw to clip space on the calling thread (MOC's own TransformVertices), then wakes the
// workers, clears the buffer, renders all triangles on them, waits, and suspends them again (awake, they spin,
// and would take the cores from the occludee test that follows).
//
// Not one SetMatrix per draw: MOC's pool keeps as many matrices as jobs in flight, so with a full queue
// SetMatrix overwrites a matrix a queued job still needs (seen here as objects wrongly culled, now and then).
void cullet_moc_pool_render(CulletMocPool* pool, const CulletMocDraw* draws, unsigned count) {
    unsigned vertices = 0;
    for (unsigned i = 0; i < count; i++) vertices += 3 * draws[i].triangles;
    pool->clip.resize(4 * (size_t)vertices);
    if (pool->indices.size() < vertices) {
        pool->indices.resize(vertices);
        for (unsigned i = 0; i < vertices; i++) pool->indices[i] = i;
    }
    float* out = pool->clip.data();
    for (unsigned i = 0; i < count; i++) {
        const unsigned n = 3 * draws[i].triangles;
        MaskedOcclusionCulling::TransformVertices(draws[i].clip_from_object, draws[i].vertices, out, n, kLayout);
        out += 4 * n;
    }
    CullingThreadpool& p = pool->pool;
    p.WakeThreads();
    p.ClearBuffer();
    p.SetMatrix(nullptr);
    p.SetVertexLayout(MaskedOcclusionCulling::VertexLayout(16, 4, 12));
    p.RenderTriangles(pool->clip.data(), pool->indices.data(), (int)(vertices / 3), kWinding);
    p.Flush();
    p.SuspendThreads();
}

}  // extern "C"
