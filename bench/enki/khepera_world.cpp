// Enki's side of bench/bench_enki.py: the engine bench's scenario in Enki (C++).
//
// Usage: khepera_world SCENARIO_FILE SIM_SECONDS
//
// SCENARIO_FILE is written by bench/bench_enki.py from bench/engine_bench.build(), so
// both simulators start from the same arena, pillars and robot poses (millimetres and
// radians; Enki works in centimetres):
//     arena SIDE_MM
//     pillar X_MM Y_MM WIDTH_MM HEIGHT_MM
//     robot X_MM Y_MM HEADING_RAD
// Every 10 ms step (World::step(0.01), physics oversampling 1): each robot's eight IR
// sensors (refreshed by that step, as Enki refreshes them every step) drive the same
// Braitenberg rule as common/sim2d/wander.py, through the same response curve
// (common/sim2d/agents/khepera.py) applied to Enki's estimated distance, so the rule
// sees the values it sees in our engine. Prints one machine-readable line:
//     enki n=N steps=S sim_s=X cpu_s=Y sim_per_cpu=Z ir_updates_per_sim_s=U inside=I
// cpu_s is this process's CPU time over the timed steps only (building the world and
// 20 warm-up steps excluded, as in bench/engine_bench.py). Exit status 2 on bad input.

#include <enki/PhysicalEngine.h>
#include <enki/robots/khepera/Khepera.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace {

constexpr double kDt = 0.01;          // the engine bench's tick (s)
constexpr int kWarmUpSteps = 20;      // as bench/engine_bench.run
constexpr double kCmPerPulseStep = 0.8;  // 0.08 mm a pulse per 10 ms = 0.8 cm/s
constexpr double kCruise = 8.0;       // wander.CRUISE, pulses per 10 ms

// common/sim2d/agents/khepera.py PROXIMITY_CURVE: distance from the sensor (mm) -> value.
const double kCurveMm[] = {0, 2, 5, 10, 15, 20, 25, 30, 35, 40, 45, 50};
const double kCurveValue[] = {1023, 1000, 870, 600, 390, 250, 160, 100, 60, 32, 12, 0};
constexpr int kCurvePoints = 12;

// wander.py: left wheel weights per sensor; the right wheel's are the mirror image.
const double kWeightLeft[8] = {4 / 400.0, 3 / 400.0, 2 / 400.0, 1 / 400.0,
                               -1 / 400.0, -2 / 400.0, 0, 0};
const int kMirror[8] = {5, 4, 3, 2, 1, 0, 6, 7};

double curve(double mm) {
    // numpy.interp's clamping at both ends; a NaN or infinite distance (no echo) reads 0.
    if (!std::isfinite(mm) || mm >= kCurveMm[kCurvePoints - 1]) return 0.0;
    if (mm <= kCurveMm[0]) return kCurveValue[0];
    for (int i = 1; i < kCurvePoints; ++i) {
        if (mm <= kCurveMm[i]) {
            const double t = (mm - kCurveMm[i - 1]) / (kCurveMm[i] - kCurveMm[i - 1]);
            return kCurveValue[i - 1] + t * (kCurveValue[i] - kCurveValue[i - 1]);
        }
    }
    return 0.0;
}

double cpu_seconds() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

[[noreturn]] void fail(const std::string& why) {
    std::cerr << "khepera_world: " << why << "\n"
              << "usage: khepera_world SCENARIO_FILE SIM_SECONDS\n";
    std::exit(2);
}

struct Pillar {
    double x, y, w, h;
};
struct Pose {
    double x, y, heading;
};

void steer(Enki::Khepera* k) {
    const Enki::IRSensor* ir[8] = {&k->infraredSensor0, &k->infraredSensor1,
                                   &k->infraredSensor2, &k->infraredSensor3,
                                   &k->infraredSensor4, &k->infraredSensor5,
                                   &k->infraredSensor6, &k->infraredSensor7};
    double value[8];
    for (int i = 0; i < 8; ++i) value[i] = curve(ir[i]->getDist() * 10.0);
    double left = kCruise, right = kCruise;
    for (int i = 0; i < 8; ++i) {
        left += value[i] * kWeightLeft[i];
        right += value[i] * kWeightLeft[kMirror[i]];
    }
    k->leftSpeed = left * kCmPerPulseStep;
    k->rightSpeed = right * kCmPerPulseStep;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 3) fail("expected two arguments");
    char* end = nullptr;
    const double sim_seconds = std::strtod(argv[2], &end);
    if (end == argv[2] || *end != '\0' || !(sim_seconds > 0) || sim_seconds > 1e6)
        fail(std::string("SIM_SECONDS must be a positive number, not ") + argv[2]);
    std::ifstream in(argv[1]);
    if (!in) fail(std::string("cannot read ") + argv[1]);

    double side_mm = -1;
    std::vector<Pillar> pillars;
    std::vector<Pose> robots;
    std::string line;
    int line_no = 0;
    while (std::getline(in, line)) {
        ++line_no;
        std::istringstream words(line);
        std::string kind;
        if (!(words >> kind)) continue;
        bool ok = false;
        if (kind == "arena") {
            ok = static_cast<bool>(words >> side_mm) && side_mm > 0;
        } else if (kind == "pillar") {
            Pillar p{};
            ok = static_cast<bool>(words >> p.x >> p.y >> p.w >> p.h) && p.w > 0 && p.h > 0;
            if (ok) pillars.push_back(p);
        } else if (kind == "robot") {
            Pose r{};
            ok = static_cast<bool>(words >> r.x >> r.y >> r.heading);
            if (ok) robots.push_back(r);
        }
        if (!ok) fail(std::string(argv[1]) + ":" + std::to_string(line_no) + ": bad line: " + line);
    }
    if (side_mm <= 0) fail("the scenario has no arena line");
    if (robots.empty()) fail("the scenario has no robots");

    const double side = side_mm / 10.0;
    Enki::World world(side, side);  // square walls from (0, 0) to (side, side)
    world.setRandomSeed(1);
    for (const Pillar& p : pillars) {
        auto* o = new Enki::PhysicalObject;  // the world owns and deletes its objects
        o->setRectangular(p.w / 10.0, p.h / 10.0, 5.0, -1);  // mass < 0: static
        o->pos = Enki::Point(p.x / 10.0, p.y / 10.0);
        world.addObject(o);
    }
    std::vector<Enki::Khepera*> kheperas;
    kheperas.reserve(robots.size());
    for (const Pose& r : robots) {
        auto* k = new Enki::Khepera;  // IR sensors on, no camera
        k->pos = Enki::Point(r.x / 10.0, r.y / 10.0);
        k->angle = r.heading;
        world.addObject(k);
        kheperas.push_back(k);
    }

    auto tick = [&]() {
        for (Enki::Khepera* k : kheperas) steer(k);
        world.step(kDt, 1);
    };
    for (int i = 0; i < kWarmUpSteps; ++i) tick();
    const long steps = std::lround(sim_seconds / kDt);
    const double cpu0 = cpu_seconds();
    for (long i = 0; i < steps; ++i) tick();
    const double cpu = cpu_seconds() - cpu0;

    size_t inside = 0;
    for (const Enki::Khepera* k : kheperas)
        if (k->pos.x >= 0 && k->pos.x <= side && k->pos.y >= 0 && k->pos.y <= side) ++inside;
    const double sim = static_cast<double>(steps) * kDt;
    std::printf("enki n=%zu steps=%ld sim_s=%.6g cpu_s=%.6g sim_per_cpu=%.6g "
                "ir_updates_per_sim_s=%.6g inside=%zu\n",
                kheperas.size(), steps, sim, cpu, cpu > 0 ? sim / cpu : INFINITY, 1.0 / kDt,
                inside);
    return 0;
}
