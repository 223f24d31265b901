/* Each kind of error has its own status, so a program acts on the status
 * and not on the message's words:
 *
 *     error_kinds DAMAGED_RUN_DIR
 *
 * where DAMAGED_RUN_DIR is a run folder whose saved map has a byte changed. */
#include <stdio.h>
#include <string.h>

#include "latentam.h"

static int expect(LatentamStatus got, LatentamStatus want, const char *what, const char *words) {
    const char *message = latentam_last_error_message();
    if (got != want || strstr(message, words) == NULL) {
        fprintf(stderr, "%s: status %d, expected %d, with \"%s\": %s\n", what, (int)got, (int)want,
                words, message);
        return 0;
    }
    return 1;
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: %s DAMAGED_RUN_DIR\n", argv[0]);
        return 2;
    }
    LatentamMapper *mapper = NULL;
    int ok = 1;
    /* Fix the setting the message names. */
    ok &= expect(latentam_mapper_new("voxel_size = -1", &mapper), LATENTAM_STATUS_CONFIG,
                 "a setting out of range", "voxel_size");
    ok &= expect(latentam_mapper_new("voxel_size = ", &mapper), LATENTAM_STATUS_CONFIG,
                 "a configuration that does not parse", "TOML");
    /* Use another copy of the file. */
    ok &= expect(latentam_mapper_load(argv[1], &mapper), LATENTAM_STATUS_DAMAGED,
                 "a saved map with a byte changed", "is damaged");
    /* Fix what was passed. */
    ok &= expect(latentam_mapper_new(NULL, NULL), LATENTAM_STATUS_INVALID_ARGUMENT, "no out pointer",
                 "out is NULL");
    if (mapper != NULL) {
        fprintf(stderr, "a failed call gave a handle\n");
        ok = 0;
    }
    if (ok) printf("every kind has its status\n");
    return ok ? 0 : 1;
}
