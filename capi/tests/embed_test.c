/* The C ABI as a C host uses it: start the service from an in-memory
 * configuration, take snapshots while it runs, read the surface, stop it
 * and check the report. Also: a bad configuration is refused with a message
 * naming the key. Exit status 0 on success; prints what it checked.
 *
 * Then the host as the device (nvtmm_start_host on rt-config/host.toml, or
 * the second argument): poses pushed at 1 kHz insert the guidewire, forces
 * come back, bad poses are refused, the surface's triangles and the wire's
 * polyline are read, and silence ramps the force to zero.
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

/* The host as the device: push poses, read forces, triangles, polylines. */
static int host_checks(const char *config) {
    NvtmmService *s = nvtmm_start_host(config, NULL, 0.0);
    CHECK(s != NULL, "nvtmm_start_host(%s): %s", config, nvtmm_last_error());
    double nan3[3] = { NAN, 0.0, 0.0 }, wild[3] = { 0.0, 0.0, 7.0 }, zero[3] = { 0.0, 0.0, 0.0 };
    CHECK(nvtmm_push_pose(s, nan3, NULL, 0) == -2, "a NaN pose is refused");
    CHECK(nvtmm_push_pose(s, zero, wild, 0) == -2, "a gimbal angle beyond 2 pi is refused");
    CHECK(nvtmm_push_pose(s, NULL, NULL, 0) == -1, "NULL is refused");
    CHECK(nvtmm_instrument_polyline(s, 99, NULL, NULL, 0) == -1, "no instrument 99");
    /* The device thread reads once the loop runs (after its jitter
     * baseline); poses pushed before fill the ring and are dropped. */
    NvtmmSnapshot snap;
    for (int k = 0; k < 400; k++) {
        CHECK(nvtmm_snapshot(s, &snap) == 0, "snapshot");
        if (snap.ticks > 0) break;
        sleep_ms(50);
    }
    CHECK(snap.ticks > 0, "the loop runs");
    /* 2 s at 1 kHz: the stylus 10 mm along -z (30 mm of wire in). */
    double peak = 0.0;
    long ok = 0;
    for (int k = 0; k < 2000; k++) {
        double pos[3] = { 0.0, 0.0, 0.0333 - 0.010 * k / 2000.0 };
        if (nvtmm_push_pose(s, pos, NULL, 0) == 0) ok++;
        double f[3];
        CHECK(nvtmm_force(s, f) == 0, "nvtmm_force");
        CHECK(isfinite(f[0]) && isfinite(f[1]) && isfinite(f[2]), "finite force");
        double m = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
        if (m > peak) peak = m;
        sleep_ms(1);
    }
    CHECK(ok > 1900, "poses accepted: %ld of 2000", ok);
    CHECK(peak > 0.0, "a force came back from the wire");
    CHECK(nvtmm_snapshot(s, &snap) == 0 && snap.frame_vertices > 0, "a frame");
    int64_t nt = nvtmm_frame_triangles(s, NULL, 0);
    CHECK(nt > 0, "triangles: %lld", (long long)nt);
    uint32_t *tri = malloc(sizeof(uint32_t) * 3 * (size_t)nt);
    float *xyz = malloc(sizeof(float) * 3 * snap.frame_vertices);
    CHECK(tri && xyz, "malloc");
    int64_t nv = nvtmm_frame_positions(s, xyz, snap.frame_vertices);
    int64_t got = nvtmm_frame_triangles(s, tri, (size_t)nt);
    CHECK(got > 0 && got <= nt, "triangles copied: %lld", (long long)got);
    for (int64_t k = 0; k < 3 * got; k++) CHECK((int64_t)tri[k] < nv, "triangle index %u < %lld", tri[k], (long long)nv);
    free(tri);
    free(xyz);
    /* The guidewire: the instrument of kind 2. */
    int64_t wi = -1, nw = 0, count = nvtmm_instrument_count(s);
    for (int64_t i = 0; i < count; i++) {
        uint8_t kind = 0;
        int64_t n = nvtmm_instrument_polyline(s, (size_t)i, &kind, NULL, 0);
        if (kind == 2) {
            wi = i;
            nw = n;
        }
    }
    CHECK(wi >= 0, "a guidewire among %lld instruments", (long long)count);
    CHECK(nw >= 2, "the wire's polyline: %lld points", (long long)nw);
    float *w = malloc(sizeof(float) * 3 * (size_t)nw);
    CHECK(w != NULL, "malloc");
    int64_t gw = nvtmm_instrument_polyline(s, (size_t)wi, NULL, w, (size_t)nw);
    CHECK(gw >= 2, "polyline copied");
    for (int64_t k = 0; k < 3 * gw; k++) CHECK(isfinite(w[k]), "finite polyline");
    printf("host: %ld poses, force peak %.3f N, %lld triangles, wire %lld points, tip (%.1f, %.1f, %.1f) mm\n", ok, peak,
           (long long)nt, (long long)gw, 1e3 * w[3 * gw - 3], 1e3 * w[3 * gw - 2], 1e3 * w[3 * gw - 1]);
    free(w);
    /* Silence: the watchdog ramps the force to zero. */
    sleep_ms(300);
    double f[3];
    CHECK(nvtmm_force(s, f) == 0 && f[0] == 0.0 && f[1] == 0.0 && f[2] == 0.0,
          "silence ramps the force to zero: (%g, %g, %g)", f[0], f[1], f[2]);
    char *report = nvtmm_stop(s);
    CHECK(report != NULL, "nvtmm_stop: %s", nvtmm_last_error());
    CHECK(strstr(report, "\"device\":\"host\"") != NULL, "the report names the host device");
    nvtmm_string_free(report);
    return 0;
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
    CHECK(nvtmm_push_pose(NULL, NULL, NULL, 0) == -1, "NULL service is refused");
    if (host_checks(argc > 2 ? argv[2] : "rt-config/host.toml") != 0) return 1;
    printf("C ABI: all checks passed\n");
    return 0;
}
