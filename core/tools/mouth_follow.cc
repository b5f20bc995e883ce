#include "core/tools/mouth_follow.h"

#include <cmath>
#include <algorithm>
#include <limits>

#include "core/util/error.h"

namespace avatar {

double PearsonCorrelation(const std::vector<double>& a, const std::vector<double>& b) {
  AVATAR_CHECK_INPUT(a.size() == b.size()) << "correlation of series of unequal length (" << a.size() << " and "
                                           << b.size() << ")";
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (a.size() < 3) return nan;
  const double n = static_cast<double>(a.size());
  double ma = 0.0, mb = 0.0;
  for (size_t i = 0; i < a.size(); ++i) {
    ma += a[i] / n;
    mb += b[i] / n;
  }
  double sab = 0.0, saa = 0.0, sbb = 0.0;
  for (size_t i = 0; i < a.size(); ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  if (!(saa > 0.0) || !(sbb > 0.0)) return nan;
  return sab / std::sqrt(saa * sbb);
}

MouthFollow MeasureMouthFollow(const std::vector<cv::Mat>& driver, const std::vector<cv::Mat>& output,
                               const face::FaceMetrics& faces, RunContext& ctx) {
  AVATAR_CHECK_INPUT(driver.size() == output.size())
      << "mouth follow needs one output frame per driver frame, got " << driver.size() << " and " << output.size();
  MouthFollow r;
  r.pairs = static_cast<int>(driver.size());
  for (size_t i = 0; i < driver.size(); ++i) {
    ctx.ThrowIfCancelled();
    ctx.Report("mouth follow", static_cast<double>(i) / std::max<size_t>(1, driver.size()));
    const face::FaceMeasurement d = faces.Measure(driver[i]);
    if (!d.found) continue;
    const face::FaceMeasurement o = faces.Measure(output[i]);
    if (!o.found) continue;
    try {
      const double dm = face::MouthOpening(d.landmarks), om = face::MouthOpening(o.landmarks);
      r.driver.push_back(dm);
      r.output.push_back(om);
    } catch (const InvalidInput&) {
      continue;  // a degenerate face height: not measurable
    }
  }
  r.measured = static_cast<int>(r.driver.size());
  r.correlation = PearsonCorrelation(r.driver, r.output);
  return r;
}

}  // namespace avatar
