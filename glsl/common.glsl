// Shared helpers for every GLSL kernel.

// Large 1-D launches are split over x and y (x is limited to 65535 groups);
// this recovers the linear workgroup index.
uint linear_group() {
    return gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
}
