#include "tests/support/flam3_oracle.h"

#include <cmath>
#include <cstdlib>
#include <fstream>

#include "absl/strings/str_cat.h"

namespace nimbus::testing {

bool HaveFlam3() { return std::system("command -v flam3-render >/dev/null 2>&1") == 0; }

std::vector<double> RenderWithFlam3(const std::string& genome, const std::string& dir,
                                    const std::string& name, int width, int height) {
  const std::string in = dir + "/" + name + ".flam3", out = dir + "/" + name + ".ppm";
  std::ofstream(in) << genome;
  const std::string cmd = absl::StrCat("env nthreads=1 verbose=0 format=ppm out=", out,
                                       " flam3-render < ", in, " > /dev/null 2>&1");
  if (std::system(cmd.c_str()) != 0) return {};
  std::ifstream ppm(out, std::ios::binary);
  std::string magic;
  int w = 0, h = 0, max = 0;
  ppm >> magic >> w >> h >> max;
  ppm.get();
  if (magic != "P6" || w != width || h != height) return {};
  std::vector<double> grey(size_t(width) * size_t(height));
  for (double& v : grey) {
    unsigned char rgb[3];
    ppm.read(reinterpret_cast<char*>(rgb), 3);
    v = rgb[0];
  }
  return ppm ? grey : std::vector<double>{};
}

double CellCorrelation(const std::vector<double>& a, const std::vector<double>& b, int width,
                       int height, int cell) {
  const int nx = width / cell, ny = height / cell;
  std::vector<double> ca(size_t(nx) * size_t(ny), 0.0), cb(ca.size(), 0.0);
  for (int y = 0; y < ny * cell; ++y)
    for (int x = 0; x < nx * cell; ++x) {
      const size_t c = size_t(y / cell) * size_t(nx) + size_t(x / cell);
      const size_t p = size_t(y) * size_t(width) + size_t(x);
      ca[c] += a[p];
      cb[c] += b[p];
    }
  double ma = 0, mb = 0;
  for (size_t i = 0; i < ca.size(); ++i) ma += ca[i], mb += cb[i];
  ma /= double(ca.size()), mb /= double(cb.size());
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < ca.size(); ++i) {
    sab += (ca[i] - ma) * (cb[i] - mb);
    saa += (ca[i] - ma) * (ca[i] - ma);
    sbb += (cb[i] - mb) * (cb[i] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

}  // namespace nimbus::testing
