// A host application as the haptic device, in C++: a game engine's device
// thread pushes the stylus pose every millisecond and reads the force back,
// while its render loop reads the surface and the guidewire at 30 Hz.
// docs/DRIVING.md, "A host application as the device".
//
// Build and run from the repository root:
//   cargo build --release -p nvtmm-capi
//   c++ -std=c++17 -Wall -Werror capi/examples/host_drive.cpp -Icapi/include -Ltarget/release -lnvtmm_capi -lpthread -o target/host_drive_cpp
//   LD_LIBRARY_PATH=target/release target/host_drive_cpp rt-config/host.toml
#include "nvtmm.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

// Owns a running service; stops it (and frees the report) on destruction.
class Service {
  public:
    explicit Service(const char *config) : s_(nvtmm_start_host(config, nullptr, 0.0)) {
        if (!s_) throw std::runtime_error(std::string("nvtmm_start_host: ") + nvtmm_last_error());
    }
    ~Service() {
        if (s_) nvtmm_string_free(nvtmm_stop(s_));
    }
    Service(const Service &) = delete;
    Service &operator=(const Service &) = delete;
    const NvtmmService *get() const { return s_; }
    std::string stop() {
        char *r = nvtmm_stop(s_);
        s_ = nullptr;
        if (!r) throw std::runtime_error(std::string("nvtmm_stop: ") + nvtmm_last_error());
        std::string out(r);
        nvtmm_string_free(r);
        return out;
    }

  private:
    NvtmmService *s_;
};

}  // namespace

int main(int argc, char **argv) {
    const char *config = argc > 1 ? argv[1] : "rt-config/host.toml";
    const double seconds = argc > 2 ? std::atof(argv[2]) : 4.0;
    try {
        Service svc(config);
        // The device thread reads once the loop runs (after its jitter baseline).
        for (int k = 0; k < 400; k++) {
            NvtmmSnapshot snap{};
            if (nvtmm_snapshot(svc.get(), &snap) != 0 || snap.ticks > 0) break;
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
        std::atomic<bool> run{true};
        std::atomic<double> peak{0.0};
        // The device thread: 1 kHz, absolute deadlines.
        std::thread device([&] {
            using clock = std::chrono::steady_clock;
            const auto t0 = clock::now();
            auto next = t0;
            while (run) {
                const double a = std::chrono::duration<double>(clock::now() - t0).count() / seconds;
                const double pos[3] = {0.0, 0.0, 0.0333 - 0.010 * std::fmin(a, 1.0)};
                const double gimbal[3] = {0.0, 0.0, 1.5708 * std::fmin(a, 1.0)};
                nvtmm_push_pose(svc.get(), pos, gimbal, 0);
                double f[3];
                nvtmm_force(svc.get(), f);
                const double m = std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
                if (m > peak) peak = m;
                next += std::chrono::milliseconds(1);
                std::this_thread::sleep_until(next);
            }
        });
        // The render loop: 30 Hz.
        std::vector<float> xyz, wire;
        std::vector<uint32_t> tri;
        const auto t0 = std::chrono::steady_clock::now();
        while (std::chrono::steady_clock::now() - t0 < std::chrono::duration<double>(seconds)) {
            NvtmmSnapshot snap{};
            nvtmm_snapshot(svc.get(), &snap);
            xyz.resize(3 * snap.frame_vertices);
            nvtmm_frame_positions(svc.get(), xyz.data(), snap.frame_vertices);
            tri.resize(3 * std::max<int64_t>(0, nvtmm_frame_triangles(svc.get(), nullptr, 0)));
            nvtmm_frame_triangles(svc.get(), tri.data(), tri.size() / 3);
            // The guidewire is the instrument of kind 2.
            wire.clear();
            for (int64_t i = 0, n = nvtmm_instrument_count(svc.get()); i < n; i++) {
                uint8_t kind = 0;
                const int64_t np = nvtmm_instrument_polyline(svc.get(), static_cast<size_t>(i), &kind, nullptr, 0);
                if (kind == 2 && np > 0) {
                    wire.resize(3 * static_cast<size_t>(np));
                    nvtmm_instrument_polyline(svc.get(), static_cast<size_t>(i), nullptr, wire.data(), wire.size() / 3);
                }
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(33));
        }
        run = false;
        device.join();
        std::printf("frame: %zu vertices, %zu triangles, wire %zu points; force peak %.3f N\n", xyz.size() / 3,
                    tri.size() / 3, wire.size() / 3, peak.load());
        if (!wire.empty())
            std::printf("wire tip at (%.1f, %.1f, %.1f) mm\n", 1e3 * wire[wire.size() - 3], 1e3 * wire[wire.size() - 2],
                        1e3 * wire[wire.size() - 1]);
        std::printf("report: %.120s...\n", svc.stop().c_str());
    } catch (const std::exception &e) {
        std::fprintf(stderr, "%s\n", e.what());
        return 1;
    }
    return 0;
}
