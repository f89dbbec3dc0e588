// Copyright 2026 toc_ros developers
//
// Licensed under the Apache License, Version 2.0 (the "License");
// you may not use this file except in compliance with the License.
// You may obtain a copy of the License at
//
//     http://www.apache.org/licenses/LICENSE-2.0
//
// Unless required by applicable law or agreed to in writing, software
// distributed under the License is distributed on an "AS IS" BASIS,
// WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
// See the License for the specific language governing permissions and
// limitations under the License.

// Pinocchio's per-node calls of the arm solver, looped in C++ (pin_batch.py builds and loads
// this file).  Every call is the one the Python bindings make (computeABADerivatives with its
// defaults, aba in the WORLD convention), resolved to the pin wheel's own compiled
// instantiations: the results are bit for bit those of the Python loop.

#include <cstring>
#include <memory>
#include <ostream>

#include <boost/asio/streambuf.hpp>

#include "pinocchio/algorithm/aba.hpp"
#include "pinocchio/algorithm/aba-derivatives.hpp"
#include "pinocchio/multibody.hpp"
#include "pinocchio/serialization.hpp"

namespace
{
typedef Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> RowMajor;
typedef Eigen::Map<const Eigen::VectorXd> ConstVector;
// The argument type of the instantiations compiled into the pin wheel's library: calls with
// it run the wheel's code (its symbols), not a copy compiled here.
typedef Eigen::Ref<const Eigen::VectorXd> Vector;
}  // namespace

extern "C" {

// A model from the bytes of pinocchio.Model.saveToBinary (nullptr when they do not load).
void * toc_model_new(const char * bytes, long size)
{
  try {
    boost::asio::streambuf buffer;
    std::ostream(&buffer).write(bytes, size);
    std::unique_ptr<pinocchio::Model> model(new pinocchio::Model());
    model->loadFromBinary(buffer);
    return model.release();
  } catch (...) {
    return nullptr;
  }
}

void toc_model_free(void * model) {delete static_cast<pinocchio::Model *>(model);}

int toc_model_nv(const void * model) {return static_cast<const pinocchio::Model *>(model)->nv;}

// A workspace of the model: one per caller thread (a Data is not shared).
void * toc_data_new(const void * model)
{
  try {
    return new pinocchio::Data(*static_cast<const pinocchio::Model *>(model));
  } catch (...) {
    return nullptr;
  }
}

void toc_data_free(void * data) {delete static_cast<pinocchio::Data *>(data);}

// For each of count nodes with state (q, v) = states[k] (rows of 2 nv) and torques tau[k]:
// the accelerations and their derivatives, and M^-1, into row-major (count, nv[, nv]) arrays.
void toc_aba_derivatives(
  const void * model_, void * data_, long count, const double * states, const double * tau,
  double * acc, double * d_q, double * d_v, double * minv)
{
  const pinocchio::Model & model = *static_cast<const pinocchio::Model *>(model_);
  pinocchio::Data & data = *static_cast<pinocchio::Data *>(data_);
  const long n = model.nv;
  for (long k = 0; k < count; ++k) {
    const double * x = states + 2 * n * k;
    pinocchio::computeABADerivatives(
      model, data, Vector(ConstVector(x, n)), Vector(ConstVector(x + n, n)),
      Vector(ConstVector(tau + n * k, n)));
    Eigen::Map<Eigen::VectorXd>(acc + n * k, n) = data.ddq;
    Eigen::Map<RowMajor>(d_q + n * n * k, n, n) = data.ddq_dq;
    Eigen::Map<RowMajor>(d_v + n * n * k, n, n) = data.ddq_dv;
    Eigen::Map<RowMajor>(minv + n * n * k, n, n) = data.Minv;
  }
}

// Explicit Euler steps x_{k+1} = x_k + step (v_k, aba(x_k, tau_k)) from states[0] = x0.
void toc_rollout_euler(
  const void * model_, void * data_, long count, const double * x0, const double * tau,
  double step, double * states)
{
  const pinocchio::Model & model = *static_cast<const pinocchio::Model *>(model_);
  pinocchio::Data & data = *static_cast<pinocchio::Data *>(data_);
  const long n = model.nv;
  std::memcpy(states, x0, sizeof(double) * 2 * n);
  for (long k = 0; k < count; ++k) {
    const double * x = states + 2 * n * k;
    double * next = states + 2 * n * (k + 1);
    pinocchio::aba(
      model, data, Vector(ConstVector(x, n)), Vector(ConstVector(x + n, n)),
      Vector(ConstVector(tau + n * k, n)), pinocchio::Convention::WORLD);
    for (long i = 0; i < n; ++i) {
      next[i] = x[i] + step * x[n + i];
      next[n + i] = x[n + i] + step * data.ddq[i];
    }
  }
}

}  // extern "C"
