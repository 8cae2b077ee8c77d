/* The C ABI as a C host uses it: start the service from an in-memory
 * configuration, take snapshots while it runs, read the surface, stop it
 * and check the report. Also: a bad configuration is refused with a message
 * naming the key. Exit status 0 on success; prints what it checked.
 *
 * Build and run (what .ci/run does):
 *   cargo build --release -p nvtmm-capi
 *   cc capi/tests/embed_test.c -Icapi/include -Ltarget/release -lnvtmm_capi -o target/embed_test
 *   LD_LIBRARY_PATH=target/release target/embed_test rt-config/embedded.toml
 */
#include "nvtmm.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <math.h>

#define CHECK(cond, ...) do { if (!(cond)) { fprintf(stderr, "FAIL: " __VA_ARGS__); fprintf(stderr, "\n"); return 1; } } while (0)

static void sleep_ms(long ms) {
    struct timespec t = { ms / 1000, (ms % 1000) * 1000000L };
    nanosleep(&t, NULL);
}

int main(int argc, char **argv) {
    /* The label/base for relative paths: a path inside rt-config/. */
    const char *label = argc > 1 ? argv[1] : "rt-config/embedded.toml";
    const char *config =
        "scene = \"scenes/arch_service.toml\"\n"
        "seconds = 2.0\n"
        "[loop]\nbaseline_s = 0.1\n"
        "[device]\nbackend = \"touchx-sim\"\ntouchx = \"touchx.toml\"\norigin_m = [0.0065, -0.031, 0.177]\n"
        "[stream]\nenabled = false\n";

    NvtmmService *bad = nvtmm_start(label, "scene = \"x.toml\"\n[loop]\nrate_hz = 5.0\n", 0.0);
    CHECK(bad == NULL, "a bad configuration must be refused");
    CHECK(strstr(nvtmm_last_error(), "loop.rate_hz") != NULL, "the error names the key: %s", nvtmm_last_error());
    printf("bad config refused: %s\n", nvtmm_last_error());

    NvtmmService *s = nvtmm_start(label, config, 0.0);
    CHECK(s != NULL, "nvtmm_start: %s", nvtmm_last_error());
    NvtmmSnapshot a, b;
    sleep_ms(800);
    CHECK(nvtmm_snapshot(s, &a) == 0, "snapshot");
    /* The first state frame comes from the publisher thread (normal
     * priority): wait for it, up to 20 s on a loaded machine. */
    for (int k = 0; k < 200; k++) {
        sleep_ms(100);
        CHECK(nvtmm_snapshot(s, &b) == 0, "snapshot");
        if (b.frame_vertices > 0 && b.ticks > a.ticks) break;
    }
    printf("ticks %llu -> %llu, force (%.3f, %.3f, %.3f) N, frame %u vertices\n",
           (unsigned long long)a.ticks, (unsigned long long)b.ticks,
           b.force_n[0], b.force_n[1], b.force_n[2], b.frame_vertices);
    CHECK(b.ticks > a.ticks, "the loop advances");
    CHECK(isfinite(b.force_n[0]) && isfinite(b.force_n[1]) && isfinite(b.force_n[2]), "finite force");
    CHECK(b.frame_vertices > 0, "a state frame is there");
    float *xyz = malloc(sizeof(float) * 3 * b.frame_vertices);
    CHECK(xyz != NULL, "malloc");
    int64_t n = nvtmm_frame_positions(s, xyz, b.frame_vertices);
    CHECK(n > 0, "positions copied: %lld", (long long)n);
    for (int64_t k = 0; k < 3 * n; k++) CHECK(isfinite(xyz[k]), "finite position");
    free(xyz);
    /* The instruments: the probe at least, its one point the tool. */
    int64_t ni = nvtmm_instrument_count(s);
    CHECK(ni >= 1, "instruments in the frame: %lld", (long long)ni);
    for (int64_t i = 0; i < ni; i++) {
        float pts[3 * 256];
        uint8_t kind = 0;
        int64_t np = nvtmm_instrument_polyline(s, (size_t)i, &kind, pts, 256);
        CHECK(np >= 1 && kind >= 1, "instrument %lld: %lld points, kind %u", (long long)i, (long long)np, kind);
        for (int64_t k = 0; k < 3 * np; k++) CHECK(isfinite(pts[k]), "finite instrument point");
        printf("instrument %lld: kind %u, %lld points\n", (long long)i, kind, (long long)np);
    }
    CHECK(nvtmm_instrument_polyline(s, (size_t)ni, NULL, NULL, 0) == -1, "an index past the count is refused");
    CHECK(nvtmm_snapshot(NULL, &a) == -1, "NULL is refused");
    char *report = nvtmm_stop(s);
    CHECK(report != NULL, "nvtmm_stop: %s", nvtmm_last_error());
    CHECK(strstr(report, "\"ticks\"") != NULL && strstr(report, "\"allocations_after_start\"") != NULL,
          "the report has its keys");
    printf("report: %.160s...\n", report);
    nvtmm_string_free(report);
    printf("C ABI: all checks passed\n");
    return 0;
}
