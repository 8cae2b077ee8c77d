/* A host application as the haptic device, in C: the host owns the device
 * (here a scripted stylus), starts the service in process with
 * nvtmm_start_host, pushes the stylus pose every millisecond, reads the
 * force back, and reads the surface's triangles and the guidewire's
 * polyline for its renderer. docs/DRIVING.md, "A host application as the
 * device".
 *
 * Build and run from the repository root:
 *   cargo build --release -p nvtmm-capi
 *   cc -std=c99 -D_POSIX_C_SOURCE=199309L -Wall -Werror capi/examples/host_drive.c \
 *      -Icapi/include -Ltarget/release -lnvtmm_capi -lm -o target/host_drive
 *   LD_LIBRARY_PATH=target/release target/host_drive rt-config/host.toml
 */
#include "nvtmm.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double now_s(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static void sleep_until(double t) {
    double d = t - now_s();
    if (d <= 0) return;
    struct timespec s = { (time_t)d, (long)((d - (time_t)d) * 1e9) };
    nanosleep(&s, NULL);
}

int main(int argc, char **argv) {
    const char *config = argc > 1 ? argv[1] : "rt-config/host.toml";
    double seconds = argc > 2 ? atof(argv[2]) : 4.0;
    NvtmmService *s = nvtmm_start_host(config, NULL, 0.0);
    if (!s) {
        fprintf(stderr, "nvtmm_start_host: %s\n", nvtmm_last_error());
        return 1;
    }
    /* The device thread reads once the loop runs (after its jitter
     * baseline): wait for the first ticks. */
    NvtmmSnapshot snap;
    for (int k = 0; k < 400 && nvtmm_snapshot(s, &snap) == 0 && snap.ticks == 0; k++) sleep_until(now_s() + 0.05);
    /* The stylus: along the hub drive's axis (device -z inserts 3 mm of wire
     * per mm, rt-config/host.toml [wire.drive]) from where the wire starts
     * (20 mm in: z = +33.3 mm), pushed 10 mm in over the run, rolled a
     * quarter turn. */
    double t0 = now_s(), next = t0, peak = 0.0;
    long pushed = 0, refused = 0;
    while (now_s() - t0 < seconds) {
        double t = now_s() - t0, a = t / seconds;
        double pos[3] = { 0.0, 0.0, 0.0333 - 0.010 * a };
        double gimbal[3] = { 0.0, 0.0, 1.5708 * a };
        if (nvtmm_push_pose(s, pos, gimbal, 0) == 0) pushed++; else refused++;
        double f[3];
        nvtmm_force(s, f);
        double m = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
        if (m > peak) peak = m;
        next += 1e-3;
        sleep_until(next);
    }
    nvtmm_snapshot(s, &snap);
    int64_t nt = nvtmm_frame_triangles(s, NULL, 0);
    /* The guidewire is the instrument of kind 2. */
    int64_t wi = -1, nw = 0, count = nvtmm_instrument_count(s);
    for (int64_t i = 0; i < count; i++) {
        uint8_t kind = 0;
        int64_t n = nvtmm_instrument_polyline(s, (size_t)i, &kind, NULL, 0);
        if (kind == 2) {
            wi = i;
            nw = n;
        }
    }
    printf("pushed %ld poses (%ld refused), force peak %.3f N, %u vertices, %lld triangles, wire %lld points\n",
           pushed, refused, peak, snap.frame_vertices, (long long)nt, (long long)nw);
    if (nw > 0) {
        float *w = malloc(sizeof(float) * 3 * (size_t)nw);
        if (w && nvtmm_instrument_polyline(s, (size_t)wi, NULL, w, (size_t)nw) == nw)
            printf("wire tip at (%.1f, %.1f, %.1f) mm\n", 1e3 * w[3 * nw - 3], 1e3 * w[3 * nw - 2], 1e3 * w[3 * nw - 1]);
        free(w);
    }
    char *report = nvtmm_stop(s);
    if (!report) {
        fprintf(stderr, "nvtmm_stop: %s\n", nvtmm_last_error());
        return 1;
    }
    printf("report: %.120s...\n", report);
    nvtmm_string_free(report);
    return 0;
}
