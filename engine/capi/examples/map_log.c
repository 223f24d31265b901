/* Maps a log through latentam's C API and prints the mapper's status:
 *
 *     cc -Wall -Werror -I engine/capi/include engine/capi/examples/map_log.c \
 *        -L target/debug -llatentam_c -Wl,-rpath,target/debug -o map_log
 *     ./map_log scene.mcap out/
 *
 * Every call returns a status; latentam_last_error_message() says why one
 * failed. */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "latentam.h"

static int check(LatentamStatus s, const char *what) {
    if (s != LATENTAM_STATUS_OK) {
        fprintf(stderr, "%s failed (%d): %s\n", what, (int)s, latentam_last_error_message());
        return 0;
    }
    return 1;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s LOG OUT_DIR\n", argv[0]);
        return 2;
    }
    LatentamMapper *mapper = NULL;
    if (!check(latentam_mapper_new(NULL, &mapper), "latentam_mapper_new")) return 1;
    LatentamLog *log = NULL;
    if (!check(latentam_log_open(argv[1], &log), "latentam_log_open")) {
        latentam_mapper_free(mapper);
        return 1;
    }
    LatentamFrame frame;
    LatentamStatus s;
    int frames = 0;
    while ((s = latentam_log_next(log, &frame)) == LATENTAM_STATUS_OK) {
        /* A log: wait for room rather than drop (a camera would call latentam_submit). */
        if (!check(latentam_submit_waiting(mapper, &frame, 600000), "latentam_submit_waiting")) break;
        frames++;
    }
    int ok = s == LATENTAM_STATUS_END_OF_LOG || check(s, "latentam_log_next");

    /* Misuse is an error code, never a crash. */
    LatentamFrame empty = frame, scaled = frame;
    empty.width = 0;
    scaled.t_world_camera[0] = 2.0; /* a scale is no rotation */
    if (latentam_submit(NULL, &frame) != LATENTAM_STATUS_INVALID_HANDLE ||
        latentam_submit(mapper, NULL) != LATENTAM_STATUS_INVALID_ARGUMENT ||
        latentam_submit(mapper, &empty) != LATENTAM_STATUS_BAD_FRAME ||
        latentam_submit(mapper, &scaled) != LATENTAM_STATUS_BAD_FRAME) {
        fprintf(stderr, "misuse was not refused\n");
        ok = 0;
    }
    latentam_log_free(log); /* the frame's buffers go with it */

    LatentamMapperStatus status = {0};
    for (;;) { /* until the worker has gone through every frame */
        ok = ok && check(latentam_status(mapper, &status), "latentam_status");
        if (!ok || status.integrated >= (uint64_t)frames) break;
        struct timespec pause = {0, 20 * 1000 * 1000};
        nanosleep(&pause, NULL);
    }
    ok = ok && check(latentam_finish(mapper), "latentam_finish");
    ok = ok && check(latentam_save(mapper, argv[2]), "latentam_save");
    latentam_mapper_free(mapper);
    /* A freed handle is known to be freed. */
    if (latentam_finish(mapper) != LATENTAM_STATUS_INVALID_HANDLE) {
        fprintf(stderr, "a freed handle was accepted\n");
        ok = 0;
    }
    printf("frames %d keyframes %llu gaussians %llu dropped %llu\n", frames,
           (unsigned long long)status.keyframes, (unsigned long long)status.gaussians,
           (unsigned long long)(status.dropped_not_keyframe + status.dropped_superseded +
                                status.dropped_rejected));
    return ok ? 0 : 1;
}
