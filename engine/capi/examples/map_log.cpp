// The C example's job through the C++ wrapper (include/latentam.hpp).
#include <cstdio>

#include "latentam.hpp"

int main(int argc, char **argv) {
    if (argc != 3) {
        std::fprintf(stderr, "usage: %s LOG OUT_DIR\n", argv[0]);
        return 2;
    }
    try {
        latentam::Mapper mapper;
        latentam::Log log(argv[1]);
        LatentamFrame frame;
        int frames = 0;
        while (log.next(frame)) {
            mapper.submit_waiting(frame, 600000);
            frames++;
        }
        mapper.finish();
        mapper.save(argv[2]);
        std::printf("frames %d\n", frames);
        return 0;
    } catch (const latentam::Error &e) {
        std::fprintf(stderr, "latentam error %d: %s\n", static_cast<int>(e.status), e.what());
        return 1;
    }
}
