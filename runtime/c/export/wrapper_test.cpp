// wrapper_test: the C++17 wrapper (abyssal_kalman.hpp) over the recorded test vectors.
//
//     wrapper_test SETUP INPUT EXPECTED TOLERANCE NIS_TOLERANCE
//
// Runs the exported filter through abyssal::KalmanFilter on INPUT (run_csv's formats: dt/u/z rows through step(), or
// time-stamped rows "t,-1,u" / "t,k,z[,R]" through predict_to() and update(sensor, z, t, R)), compares x, P and the
// codes with EXPECTED (compare_csv's tolerances), checks that a copy of the filter is an exact checkpoint (copy, run
// both on the same rows: bit-identical) and that a refused call changes nothing. Exit 0 when all pass.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "abyssal_exported.h"
#include "abyssal_kalman.hpp"

namespace {

using Filter = abyssal::KalmanFilter<ABYSSAL_EXPORTED_N_X, ABYSSAL_EXPORTED_N_U, ABYSSAL_EXPORTED_N_Y,
                                     ABYSSAL_EXPORTED_N_P>;

std::vector<double> numbers(const std::string& text) {
  std::vector<double> out;
  const char* p = text.c_str();
  while (*p) {
    char* end = nullptr;
    double value = std::strtod(p, &end);
    if (end == p) {
      ++p;
      continue;
    }
    out.push_back(value);
    p = end;
  }
  return out;
}

template <class Array>
void fill(Array& out, const std::vector<double>& values) {
  if (values.size() != out.size()) throw std::runtime_error("a setup line has the wrong number of values");
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = values[i];
}

struct Row {
  double dt;  // or the time stamp t of a time-stamped call
  Filter::Input u;
  Filter::Measurement z;
  bool measured;
  int call;               // time-stamped rows: -1 predict_to, k >= 0 sensor k's update
  std::vector<double> R;  // a time-stamped update's own R (empty: the filter's)
};

// One row through the wrapper: step(), or the time-stamped call.
int apply(Filter& filter, const Row& row, bool stamped) {
  if (!stamped) return row.measured ? filter.step(row.u, row.dt, row.z) : filter.step(row.u, row.dt);
  if (row.call == -1) return filter.predict_to(row.dt, row.u);
  return filter.update(row.call, row.z.data(), row.dt, row.R.empty() ? nullptr : row.R.data());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 6) {
    std::cerr << "usage: wrapper_test SETUP INPUT EXPECTED TOLERANCE NIS_TOLERANCE\n";
    return 2;
  }
  const double tolerance = std::strtod(argv[4], nullptr), nis_tolerance = std::strtod(argv[5], nullptr);
  abyssal_kalman_options options = abyssal_kalman_default_options(ABYSSAL_EXPORTED_FILTER);
  Filter::State x0{};
  Filter::Covariance P0{}, Q{};
  Filter::MeasurementCovariance R{};
  std::ifstream setup(argv[1]);
  for (std::string line; std::getline(setup, line);) {
    std::istringstream words(line);
    std::string name;
    if (!(words >> name) || name[0] == '#') continue;
    std::string rest;
    std::getline(words, rest);
    const std::vector<double> values = numbers(rest);
    if (name == "x0") fill(x0, values);
    else if (name == "P0") fill(P0, values);
    else if (name == "Q") fill(Q, values);
    else if (name == "R") fill(R, values);
    else if (name == "gate_probability") options.gate_probability = values.at(0);
    else if (name == "gate_patience") options.gate_patience = static_cast<int>(values.at(0));
    else if (name == "gate_inflation") options.gate_inflation = values.at(0);
    else if (name == "growth_limit") options.growth_limit = values.at(0);
    else if (name == "max_substeps") options.max_substeps = static_cast<int>(values.at(0));
    else if (name == "repair_floor") options.repair_floor = values.at(0);
    else if (name == "alpha") options.alpha = values.at(0);
    else if (name == "beta") options.beta = values.at(0);
    else if (name == "kappa") options.kappa = values.at(0);
    else if (name == "sigma") options.sigma = values.at(0);
    else if (name == "gamma") options.gamma = values.at(0);
    else if (name == "huber_iterations") options.huber_iterations = static_cast<int>(values.at(0));
    else if (name == "gate_max_inflations") options.gate_max_inflations = static_cast<int>(values.at(0));
    else if (name == "noise") options.noise = static_cast<int>(values.at(0));
    else if (name == "history_entries") options.history_entries = static_cast<int>(values.at(0));
    else if (name == "history_seconds") options.history_seconds = values.at(0);
    else if (name == "smoothing") options.smoothing = static_cast<int>(values.at(0));
    else {
      std::cerr << "wrapper_test: unknown setup line " << name << "\n";
      return 2;
    }
  }
  std::vector<Row> rows;
  std::ifstream input(argv[2]);
  std::string line;
  std::getline(input, line);  // header
  const bool stamped = line.rfind("t,", 0) == 0;
  const abyssal_model& model = *ABYSSAL_EXPORTED_MODEL;
  while (std::getline(input, line)) {
    const std::vector<double> v = numbers(line);
    Row row{};
    row.dt = v.at(0);
    row.measured = false;
    if (stamped) {
      row.call = static_cast<int>(v.at(1));
      const std::size_t given = v.size() - 2;
      if (row.call == -1) {
        for (std::size_t i = 0; i < row.u.size(); ++i) row.u[i] = v.at(2 + i);
      } else {
        const std::size_t m = row.call >= 0 && row.call < model.n_sensors ? model.sensors[row.call].n_y : given;
        for (std::size_t i = 0; i < m && i < row.z.size(); ++i) row.z[i] = v.at(2 + i);
        if (given > m) row.R.assign(v.begin() + 2 + static_cast<long>(m), v.end());
      }
    } else {
      for (std::size_t i = 0; i < row.u.size(); ++i) row.u[i] = v.at(1 + i);
      for (std::size_t i = 0; i < row.z.size(); ++i) {
        row.z[i] = v.at(1 + row.u.size() + i);
        row.measured = row.measured || !std::isnan(row.z[i]);
      }
    }
    rows.push_back(row);
  }
  std::map<long, std::vector<double>> expected;
  std::ifstream recorded(argv[3]);
  std::getline(recorded, line);  // header
  while (std::getline(recorded, line)) {
    std::vector<double> v = numbers(line);
    expected[static_cast<long>(v.at(0))] = v;
  }

  Filter filter(*ABYSSAL_EXPORTED_MODEL, options, x0, P0, Q, R);
  int failures = 0, refused = 0;
  double worst = 0.0;
  const std::size_t n = ABYSSAL_EXPORTED_N_X;
  for (std::size_t k = 0; k < rows.size(); ++k) {
    const Row& row = rows[k];
    const std::array<double, n> before = filter.x().array();
    const int code = apply(filter, row, stamped);
    if (code < 0) {  // refused: nothing changed
      ++refused;
      if (filter.x().array() != before) {
        std::cerr << "step " << k << ": refused (" << Filter::message(code) << ") but x changed\n";
        ++failures;
      }
    }
    auto found = expected.find(static_cast<long>(k));
    if (found == expected.end()) continue;
    const std::vector<double>& e = found->second;
    if (e.at(1) != code) {
      std::cerr << "step " << k << ": code " << code << ", expected " << e.at(1) << "\n";
      ++failures;
    }
    std::vector<double> ours;
    ours.push_back(code == ABYSSAL_UPDATED ? filter.report().nis : NAN);
    for (std::size_t i = 0; i < n; ++i) ours.push_back(filter.x()[i]);
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = i; j < n; ++j) ours.push_back(filter.P()(i, j));
    if (ours.size() + 2 != e.size()) {
      std::cerr << "step " << k << ": " << e.size() << " expected columns\n";
      return 1;
    }
    for (std::size_t c = 0; c < ours.size(); ++c) {
      const double want = e[c + 2];
      const double difference = (std::isnan(want) && std::isnan(ours[c])) ? 0.0
                                : std::fabs(ours[c] - want) / std::fmax(1.0, std::fabs(want));
      if (c == 0) {  // the NIS
        if (!(difference <= nis_tolerance)) ++failures;
        continue;
      }
      if (!(difference <= worst)) worst = std::isnan(difference) ? INFINITY : difference;
      if (!(difference <= tolerance)) ++failures;
    }
  }
  // A copy is a checkpoint: both filters go on bit-identically.
  Filter copy = filter;
  if (stamped) {  // the stamps go on from the end of the run
    const double t0 = filter.t();
    for (std::size_t k = 0; k < 50 && k < rows.size(); ++k) {
      Row row = rows[k];
      row.dt += t0;
      apply(filter, row, true);
      apply(copy, row, true);
    }
  } else {
    for (std::size_t k = 0; k < 50 && k < rows.size(); ++k) {
      apply(filter, rows[k], false);
      apply(copy, rows[k], false);
    }
  }
  if (filter.x().array() != copy.x().array() || filter.P().array() != copy.P().array()) {
    std::cerr << "a copied filter diverged from its original\n";
    ++failures;
  }
  std::cout << rows.size() << (stamped ? " time-stamped calls" : " steps") << " through abyssal::KalmanFilter (" << filter.bytes() << " bytes, " << refused
            << " refused); largest relative difference from the recorded vectors " << worst << " (tolerance "
            << tolerance << "): " << (failures ? "FAILED" : "passed") << "\n";
  return failures ? 1 : 0;
}
