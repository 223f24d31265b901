// A header-only C++17 wrapper of latentam's C API (latentam.h): handles
// freed by their destructors (RAII, move-only), failures thrown as
// latentam::Error carrying the status and the engine's message.
//
//     latentam::Mapper mapper;                 // or Mapper("gpu_budget = 2_000_000_000")
//     mapper.submit(frame);                    // a LatentamFrame; returns at once
//     std::vector<float> scores = mapper.query(text_embedding);
//     mapper.finish();
//     mapper.save("run/");
#ifndef LATENTAM_HPP
#define LATENTAM_HPP

#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "latentam.h"

namespace latentam {

/// A failed call: what() is the engine's message, status its kind (e.g.
/// LATENTAM_STATUS_CONFIG: fix the setting named; LATENTAM_STATUS_DAMAGED:
/// use another copy of the file; LATENTAM_STATUS_BUDGET: raise the budget).
class Error : public std::runtime_error {
public:
    Error(LatentamStatus status, const char *message)
        : std::runtime_error(message), status(status) {}
    LatentamStatus status;
};

inline void check(LatentamStatus status) {
    if (status != LATENTAM_STATUS_OK) throw Error(status, latentam_last_error_message());
}

/// The live mapper (see latentam.h for each call's rules).
class Mapper {
public:
    explicit Mapper(const char *config_toml = nullptr) {
        LatentamMapper *m = nullptr;
        check(latentam_mapper_new(config_toml, &m));
        handle_.reset(m);
    }
    static Mapper load(const std::string &dir) {
        LatentamMapper *m = nullptr;
        check(latentam_mapper_load(dir.c_str(), &m));
        return Mapper(m);
    }
    void submit(const LatentamFrame &frame) { check(latentam_submit(handle_.get(), &frame)); }
    void submit_waiting(const LatentamFrame &frame, unsigned max_wait_ms) {
        check(latentam_submit_waiting(handle_.get(), &frame, max_wait_ms));
    }
    LatentamMapperStatus status() const {
        LatentamMapperStatus s{};
        check(latentam_status(handle_.get(), &s));
        return s;
    }
    /// Cosine relevance of every Gaussian to a text embedding.
    std::vector<float> query(const std::vector<float> &text) const {
        std::vector<float> scores;
        for (;;) {  // the map may grow between the size and the answer
            size_t count = 0;
            LatentamStatus s = latentam_query(handle_.get(), text.data(), text.size(),
                                              scores.data(), scores.size(), &count);
            if (s == LATENTAM_STATUS_OK) {
                scores.resize(count);
                return scores;
            }
            if (s != LATENTAM_STATUS_BUFFER_TOO_SMALL) check(s);
            scores.resize(count + count / 8 + 16);
        }
    }
    void save(const std::string &dir) { check(latentam_save(handle_.get(), dir.c_str())); }
    void finish() { check(latentam_finish(handle_.get())); }
    LatentamMapper *get() const { return handle_.get(); }

private:
    explicit Mapper(LatentamMapper *m) : handle_(m) {}
    struct Free {
        void operator()(LatentamMapper *m) const { latentam_mapper_free(m); }
    };
    std::unique_ptr<LatentamMapper, Free> handle_;
};

/// The frames of a log; next() fills a frame valid until the next call.
class Log {
public:
    explicit Log(const std::string &path) {
        LatentamLog *l = nullptr;
        check(latentam_log_open(path.c_str(), &l));
        handle_.reset(l);
    }
    /// False after the last frame.
    bool next(LatentamFrame &frame) {
        LatentamStatus s = latentam_log_next(handle_.get(), &frame);
        if (s == LATENTAM_STATUS_END_OF_LOG) return false;
        check(s);
        return true;
    }

private:
    struct Free {
        void operator()(LatentamLog *l) const { latentam_log_free(l); }
    };
    std::unique_ptr<LatentamLog, Free> handle_;
};

}  // namespace latentam

#endif
