// server: the loop of a C++ PSAO server with its own "ray tracer", through
// the C API. One instance (a sphere of points) is shaded by an occluder
// that circles it; every tick the server updates the points whose AO
// changed past the thresholds and encodes a delta with the instance's new
// transform. It writes its frames to OUT_DIR/frames.bin (each as a 4-byte
// little-endian length and the frame) and, at the end, its table's bucket
// entries and words to OUT_DIR/table.bin, so a client can check its mirror.
//
//   c++ -std=c++17 -I include psao-ffi/examples/cpp/server.cpp
//       target/release/libpsao_ffi.a -lm -lpthread -ldl -o server   (one line)
//   ./server OUT_DIR [TICKS]
//
// A keyframe opens the stream and another is sent halfway (for a late
// joiner); frames are written through a deliberately small buffer first,
// to show the PSAO_ERROR_BUFFER_TOO_SHORT retry.

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "psao.h"

namespace {

// Owners that free the C objects.
struct TableFree {
    void operator()(psao_table *t) const { psao_table_free(t); }
};
struct EncoderFree {
    void operator()(psao_encoder *e) const { psao_encoder_free(e); }
};
using Table = std::unique_ptr<psao_table, TableFree>;
using Encoder = std::unique_ptr<psao_encoder, EncoderFree>;

[[noreturn]] void die(const char *what, psao_result r, const std::string &detail) {
    std::fprintf(stderr, "%s: %s: %s\n", what, psao_result_name(r), detail.c_str());
    std::exit(1);
}

// A failure's message: this thread's last object-less call's (a
// constructor that failed has no object to keep it), or an object's.
std::string message(psao_result (*last_error)(char *, size_t, size_t *)) {
    char buf[512];
    size_t len = 0;
    if (last_error(buf, sizeof buf, &len) != PSAO_OK) return "(no message)";
    return buf;
}

template <typename T>
std::string message(T *object, psao_result (*last_error)(T *, char *, size_t, size_t *)) {
    char buf[512];
    size_t len = 0;
    if (last_error(object, buf, sizeof buf, &len) != PSAO_OK) return "(no message)";
    return buf;
}

std::string thread_error() { return message(psao_last_error); }

void check(psao_result r, psao_encoder *e, const char *what) {
    if (r != PSAO_OK) die(what, r, message(e, psao_encoder_last_error));
}

void check(psao_result r, psao_table *t, const char *what) {
    if (r != PSAO_OK) die(what, r, message(t, psao_table_last_error));
}

struct Point {
    float pos[3];
    float normal[3];
};

// Points spread over a sphere of radius 0.8 (a Fibonacci spiral).
std::vector<Point> sphere_points(uint32_t n) {
    std::vector<Point> pts(n);
    const float golden = 2.39996323f;
    for (uint32_t i = 0; i < n; i++) {
        float y = 1.0f - 2.0f * (static_cast<float>(i) + 0.5f) / static_cast<float>(n);
        float r = std::sqrt(1.0f - y * y);
        float phi = golden * static_cast<float>(i);
        float nx = r * std::cos(phi), nz = r * std::sin(phi);
        pts[i] = {{0.8f * nx, 0.8f * y, 0.8f * nz}, {nx, y, nz}};
    }
    return pts;
}

// The stand-in for a ray tracer: AO darkens towards an occluder at `occ`.
float shade(const Point &p, const float occ[3]) {
    float d2 = 0.0f;
    for (int k = 0; k < 3; k++) d2 += (p.pos[k] - occ[k]) * (p.pos[k] - occ[k]);
    return 1.0f - 0.85f * std::exp(-3.0f * d2);
}

// Collects the open frame through a growing buffer, as a server with a
// reusable send buffer would.
struct FrameSink {
    std::vector<uint8_t> buf = std::vector<uint8_t>(64);
    std::FILE *out;
    uint32_t frames = 0, retries = 0;

    void finish(psao_encoder *enc) {
        size_t len = 0;
        psao_frame_info info{};
        psao_result r = psao_encoder_finish(enc, buf.data(), buf.size(), &len, &info);
        if (r == PSAO_ERROR_BUFFER_TOO_SHORT) {
            retries++;
            buf.resize(len);
            r = psao_encoder_finish(enc, buf.data(), buf.size(), &len, &info);
        }
        check(r, enc, "psao_encoder_finish");
        if (len == 0) return;  // an empty delta is no frame
        uint8_t head[4] = {static_cast<uint8_t>(len), static_cast<uint8_t>(len >> 8),
                           static_cast<uint8_t>(len >> 16), static_cast<uint8_t>(len >> 24)};
        if (std::fwrite(head, 1, 4, out) != 4 || std::fwrite(buf.data(), 1, len, out) != len) {
            std::perror("write frames.bin");
            std::exit(1);
        }
        frames++;
    }
};

}  // namespace

int main(int argc, char **argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s OUT_DIR [TICKS]\n", argv[0]);
        return 2;
    }
    const std::string dir = argv[1];
    const int ticks = argc > 2 ? std::atoi(argv[2]) : 60;
    const uint32_t instance = 7, n_points = 3000;

    psao_instance_def def{};
    for (int k = 0; k < 3; k++) {
        def.origin[k] = -1.0f;
        def.cell_size[k] = 0.125f;
        def.dims[k] = 16;
    }
    def.table_log2 = 10;
    def.bucket_capacity = 8;
    def.cell_capacity = 7;
    def.point_format = 0;
    def.overflow = 1;
    def.cell_pool = 2048;
    def.radius = 0.12f;
    def.t_n = 0.1f;
    def.t_d = 0.7f;

    psao_table *raw_table = nullptr;
    psao_result r = psao_table_new(instance, &def, n_points, nullptr, &raw_table);
    if (r != PSAO_OK) die("psao_table_new", r, thread_error());
    Table table(raw_table);

    psao_encoder_config config = psao_encoder_config_default();
    config.compression = PSAO_COMPRESSION_ZSTD;
    psao_encoder *raw_encoder = nullptr;
    r = psao_encoder_new(&config, 0, &raw_encoder);
    if (r != PSAO_OK) die("psao_encoder_new", r, thread_error());
    Encoder enc(raw_encoder);

    std::FILE *frames = std::fopen((dir + "/frames.bin").c_str(), "wb");
    if (!frames) {
        std::perror("frames.bin");
        return 1;
    }
    FrameSink sink{};
    sink.out = frames;

    // The stream opens with a keyframe of the (empty) table.
    check(psao_encoder_begin(enc.get(), 1), enc.get(), "begin keyframe");
    check(psao_encoder_snapshot(enc.get(), table.get()), enc.get(), "snapshot");
    sink.finish(enc.get());

    const std::vector<Point> points = sphere_points(n_points);
    const psao_thresholds thresholds = psao_thresholds_default();
    uint64_t updates = 0;
    for (int tick = 1; tick <= ticks; tick++) {
        const float a = 0.2f * static_cast<float>(tick);
        const float occ[3] = {1.1f * std::cos(a), 0.3f * std::sin(0.5f * a), 1.1f * std::sin(a)};
        for (uint32_t i = 0; i < n_points; i++) {
            uint8_t sent = 0;
            check(psao_table_update_point(table.get(), i, points[i].pos, points[i].normal,
                                          shade(points[i], occ), &thresholds, &sent),
                  table.get(), "update_point");
            updates += sent;
        }
        // The instance turns slowly about y.
        const float t = 0.05f * static_cast<float>(tick);
        psao_transform xf{static_cast<uint32_t>(tick),
                          {std::cos(t), 0, -std::sin(t), 0, 1, 0, std::sin(t), 0, std::cos(t),
                           0.5f, 0, -2.0f}};
        check(psao_encoder_begin(enc.get(), 0), enc.get(), "begin delta");
        check(psao_encoder_transform(enc.get(), instance, &xf), enc.get(), "transform");
        check(psao_encoder_changes(enc.get(), table.get()), enc.get(), "changes");
        sink.finish(enc.get());

        if (tick == ticks / 2) {
            // A keyframe for a late joiner: the state at the current
            // sequence, transform included.
            check(psao_encoder_begin(enc.get(), 1), enc.get(), "begin keyframe");
            check(psao_encoder_snapshot(enc.get(), table.get()), enc.get(), "snapshot");
            check(psao_encoder_transform(enc.get(), instance, &xf), enc.get(), "transform");
            sink.finish(enc.get());
        }
    }
    std::fclose(frames);

    // The table as the server holds it, for the client's check.
    psao_table_stats stats{};
    check(psao_table_get_stats(table.get(), &stats), table.get(), "stats");
    const size_t entries = (size_t{1} << def.table_log2) * def.bucket_capacity;
    const size_t words = size_t{def.cell_pool} * def.cell_capacity;
    std::vector<psao_bucket_entry> bucket_entries(entries);
    std::vector<uint32_t> word_list(words);
    check(psao_table_copy_buckets(table.get(), 0, entries, bucket_entries.data()), table.get(),
          "copy_buckets");
    check(psao_table_copy_words(table.get(), 0, words, word_list.data()), table.get(),
          "copy_words");
    std::FILE *dump = std::fopen((dir + "/table.bin").c_str(), "wb");
    if (!dump) {
        std::perror("table.bin");
        return 1;
    }
    auto put_u32 = [&](uint32_t v) {
        uint8_t b[4] = {static_cast<uint8_t>(v), static_cast<uint8_t>(v >> 8),
                        static_cast<uint8_t>(v >> 16), static_cast<uint8_t>(v >> 24)};
        std::fwrite(b, 1, 4, dump);
    };
    put_u32(instance);
    put_u32(static_cast<uint32_t>(entries));
    for (const auto &e : bucket_entries) {
        put_u32(e.key);
        put_u32(e.cell);
    }
    put_u32(static_cast<uint32_t>(words));
    for (uint32_t w : word_list) put_u32(w);
    std::fclose(dump);

    uint32_t sequence = 0;
    check(psao_encoder_sequence(enc.get(), &sequence), enc.get(), "sequence");
    std::printf("psao %s server: %d ticks, %u frames (%u buffer retries), sequence %u, "
                "%llu point updates, %u stored, %u dropped\n",
                psao_version(), ticks, sink.frames, sink.retries, sequence,
                static_cast<unsigned long long>(updates), stats.stored, stats.dropped);
    return 0;
}
