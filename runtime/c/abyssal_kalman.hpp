// abyssal_kalman.hpp: a header-only C++17 wrapper of the Kalman runtime (abyssal_kalman.h).
//
//     #include "rov4dof_filter.h"       // the exported model: rov4dof_descriptor, sizes
//     #include "abyssal_kalman.hpp"
//     using Filter = abyssal::KalmanFilter<12, 4, 4, 17>;   // n_x, n_u, n_y, n_p (the header names them)
//     Filter ckf(rov4dof_descriptor, abyssal_kalman_default_options(ABYSSAL_CKF), x0, P0, Q, R);
//     int code = ckf.step(u, 0.1, z);    // std::array arguments; z optional; >= 0 success, < 0 refused
//     ckf.predict_to(t, u);              // time-stamped: integrate to t with u held
//     ckf.update(0, z_fix, t_fix);       // sensor 0's measurement stamped t_fix (late: fused from the history)
//     double north = ckf.x()[0];         // views into the filter object, valid until its next call
//
// RAII: the constructor allocates the filter object once (the only allocation; none per step) and checks
// everything abyssal_kalman_init checks, throwing std::invalid_argument with the runtime's message; the
// destructor frees it. Copies are independent filters (the object holds no pointers, so a copy is a memcpy: a
// checkpoint); the wrapper keeps the model's descriptor beside it. Calls return the runtime's codes; nothing throws
// after construction. A moved-from wrapper's calls return ABYSSAL_E_MEMORY and its views read NaN. One filter, one
// thread.
#ifndef ABYSSAL_KALMAN_HPP
#define ABYSSAL_KALMAN_HPP

#include <array>
#include <cstddef>
#include <cstring>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>

#include "abyssal_kalman.h"

namespace abyssal {

// A read-only view of N doubles in the filter object (a vector, or an R x C column-major matrix).
template <std::size_t N>
class View {
 public:
  explicit View(const double* data) : data_(data) {}
  double operator[](std::size_t i) const { return data_[i]; }
  const double* data() const { return data_; }
  const double* begin() const { return data_; }
  const double* end() const { return data_ + N; }
  static constexpr std::size_t size() { return N; }
  // A copy of the viewed values.
  std::array<double, N> array() const {
    std::array<double, N> out{};
    std::memcpy(out.data(), data_, sizeof(double) * N);
    return out;
  }

 private:
  const double* data_;
};

template <std::size_t R, std::size_t C>
class MatrixView : public View<R * C> {
 public:
  explicit MatrixView(const double* data) : View<R * C>(data) {}
  double operator()(std::size_t row, std::size_t column) const { return this->data()[row + column * R]; }
};

template <std::size_t NX, std::size_t NU, std::size_t NY, std::size_t NP>
class KalmanFilter {
 public:
  using State = std::array<double, NX>;
  using Input = std::array<double, NU>;
  using Measurement = std::array<double, NY>;
  using Parameters = std::array<double, NP>;
  using Covariance = std::array<double, NX * NX>;            // column-major
  using MeasurementCovariance = std::array<double, NY * NY>;  // column-major
  using Mask = std::array<unsigned char, NY>;                 // 1: use the entry, 0: leave it out

  KalmanFilter(const abyssal_model& model, const abyssal_kalman_options& options, const State& x0,
               const Covariance& P0, const Covariance& Q, const MeasurementCovariance& R, double t0 = 0.0)
      : model_(&model) {
    if (model.n_x != static_cast<int>(NX) || model.n_u != static_cast<int>(NU) || model.n_y != static_cast<int>(NY) ||
        model.n_p != static_cast<int>(NP))
      throw std::invalid_argument(std::string("abyssal::KalmanFilter: the model ") + model.name +
                                  " has other sizes than the template's");
    bytes_ = abyssal_kalman_work_size(&model, &options);
    if (bytes_ == 0) throw std::invalid_argument(message(abyssal_kalman_check_options(&model, &options)));
    memory_.reset(new double[(bytes_ + 7) / 8]);
    int code = abyssal_kalman_init(memory_.get(), bytes_, &model, &options, x0.data(), P0.data(), Q.data(), R.data(),
                                   t0, &filter_);
    if (code != ABYSSAL_OK) throw std::invalid_argument(message(code));
  }

  KalmanFilter(const KalmanFilter& other) : model_(other.model_), bytes_(other.bytes_) {
    if (other.filter_) {
      memory_.reset(new double[(other.bytes_ + 7) / 8]);
      std::memcpy(memory_.get(), other.memory_.get(), bytes_);
      filter_ = reinterpret_cast<abyssal_kalman*>(memory_.get());
    }
  }
  KalmanFilter& operator=(const KalmanFilter& other) {
    if (this != &other) {
      KalmanFilter copy(other);
      *this = std::move(copy);
    }
    return *this;
  }
  KalmanFilter(KalmanFilter&& other) noexcept
      : model_(other.model_), bytes_(other.bytes_), memory_(std::move(other.memory_)), filter_(other.filter_) {
    other.bytes_ = 0;
    other.filter_ = nullptr;
  }
  KalmanFilter& operator=(KalmanFilter&& other) noexcept {
    if (this == &other) return *this;  // a self-move keeps the filter
    model_ = other.model_;
    bytes_ = other.bytes_;
    memory_ = std::move(other.memory_);
    filter_ = other.filter_;
    other.bytes_ = 0;
    other.filter_ = nullptr;
    return *this;
  }
  ~KalmanFilter() = default;

  // predict(u, dt, p) then update(z, p) of every sensor stacked, as one transaction; NaN entries of z are left out.
  int step(const Input& u, double dt) { return abyssal_kalman_step(filter_, model_, u.data(), dt, nullptr, nullptr, nullptr); }
  int step(const Input& u, double dt, const Measurement& z) {
    return abyssal_kalman_step(filter_, model_, u.data(), dt, z.data(), nullptr, nullptr);
  }
  int step(const Input& u, double dt, const Measurement& z, const Mask& mask) {
    return abyssal_kalman_step(filter_, model_, u.data(), dt, z.data(), mask.data(), nullptr);
  }
  int step(const Input& u, double dt, const Measurement& z, const Parameters& p) {
    return abyssal_kalman_step(filter_, model_, u.data(), dt, z.data(), nullptr, p.data());
  }
  int predict(const Input& u, double dt) { return abyssal_kalman_predict(filter_, model_, u.data(), dt, nullptr); }
  int predict(const Input& u, double dt, const Parameters& p) {
    return abyssal_kalman_predict(filter_, model_, u.data(), dt, p.data());
  }
  int update(const Measurement& z) { return abyssal_kalman_update(filter_, model_, z.data(), nullptr, nullptr); }
  int update(const Measurement& z, const Mask& mask) {
    return abyssal_kalman_update(filter_, model_, z.data(), mask.data(), nullptr);
  }
  // time-stamped: integrate to t with u held; one sensor's measurement (its outputs: a pointer to n_y_k values)
  int predict_to(double t, const Input& u) { return abyssal_kalman_predict_to(filter_, model_, t, u.data(), nullptr); }
  int predict_to(double t, const Input& u, const Parameters& p) {
    return abyssal_kalman_predict_to(filter_, model_, t, u.data(), p.data());
  }
  // as Python's update(sensor, z, t, R, p): z its n_y_k outputs (NaN: missing), R its own n_y_k x n_y_k covariance
  // (column-major; nullptr: the filter's), q its own parameters (nullptr: those held)
  int update(int sensor, const double* z, double t, const double* R = nullptr, const double* q = nullptr) {
    return abyssal_kalman_update_sensor(filter_, model_, sensor, t, z, nullptr, R, q);
  }
  int update(const char* sensor, const double* z, double t, const double* R = nullptr, const double* q = nullptr) {
    return update(abyssal_kalman_sensor_index(model_, sensor), z, t, R, q);
  }
  int reset(const State& x, const Covariance& P) { return abyssal_kalman_reset(filter_, x.data(), P.data()); }

  View<NX> x() const { return View<NX>(filter_ ? abyssal_kalman_x(filter_) : nans().data()); }
  MatrixView<NX, NX> P() const { return MatrixView<NX, NX>(filter_ ? abyssal_kalman_P(filter_) : nans().data()); }
  double t() const { return abyssal_kalman_time(filter_); }
  abyssal_kalman_report report() const {
    abyssal_kalman_report r;
    abyssal_kalman_get_report(filter_, &r);
    return r;
  }
  abyssal_sensor_report sensor_report(int sensor) const {
    abyssal_sensor_report r{};
    abyssal_kalman_get_sensor_report(filter_, sensor, &r);
    return r;
  }
  std::size_t bytes() const { return bytes_; }
  const abyssal_kalman* get() const { return filter_; }
  const abyssal_model& model() const { return *model_; }
  static std::string message(int code) { return abyssal_kalman_message(code); }

 private:
  // what a moved-from wrapper's views read
  static const std::array<double, NX * NX>& nans() {
    static const std::array<double, NX * NX> values = [] {
      std::array<double, NX * NX> a{};
      a.fill(std::numeric_limits<double>::quiet_NaN());
      return a;
    }();
    return values;
  }
  const abyssal_model* model_ = nullptr;
  std::size_t bytes_ = 0;
  std::unique_ptr<double[]> memory_;
  abyssal_kalman* filter_ = nullptr;
};

}  // namespace abyssal

#endif  // ABYSSAL_KALMAN_HPP
