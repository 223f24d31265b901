// Shared by the SSIM kernels (ssim_*.comp): the window, the constants and the
// per-view indexing. One thread per (pixel, channel) of one view; the view's
// pixels start at `first_pixel` of the batch images, while the per-view
// scratch buffers are indexed from 0.

#define THREADS 256
#define RADIUS 5
#define C1 0.0001
#define C2 0.0009

// Normalised 11-tap Gaussian, sigma 1.5 (the 2-D window is its outer product).
float tap(int k) {
    float w[11] = float[11](0.001028380, 0.007598758, 0.036000772, 0.109360690, 0.213005538,
                           0.266011725, 0.213005538, 0.109360690, 0.036000772, 0.007598758,
                           0.001028380);
    return w[k + RADIUS];
}

// @push Ssim
layout(push_constant) uniform Params {
    uint width;
    uint height;
    uint first_pixel;
    uint partial_offset;
    float weight;
} pc;

// This thread's (pixel, channel) in the view, or false past the end.
bool ssim_item(out uint p, out uint c, out uint u, out uint v) {
    uint i = linear_group() * THREADS + gl_LocalInvocationID.x;
    p = i / 3u;
    c = i % 3u;
    u = p % pc.width;
    v = p / pc.width;
    return i < pc.width * pc.height * 3u;
}
