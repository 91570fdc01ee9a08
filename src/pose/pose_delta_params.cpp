#include "structured_light_stabilizer/pose/pose_delta_params.h"

#include <sstream>

namespace structured_light_stabilizer
{

std::string PoseDeltaParams::validate() const
{
  std::ostringstream why;
  if (min_points < 6)
    why << "min_points must be at least 6 (six unknowns); ";
  if (max_iterations < 1)
    why << "max_iterations must be positive; ";
  if (!(huber_k > 0.0))
    why << "huber_k must be positive; ";
  if (!(min_geometry_sigma_m > 0.0) || !(min_texture_sigma_px > 0.0))
    why << "noise floors must be positive; ";
  if (!(prior_sigma_translation_m > 0.0) || !(prior_sigma_rotation_rad > 0.0))
    why << "prior sigmas must be positive; ";
  if (!(max_sigma_translation_m > 0.0) || !(max_sigma_rotation_deg > 0.0) || !(max_rms_residual_m > 0.0))
    why << "validity bounds must be positive; ";
  if (!(freeze_factor >= 1.0))
    why << "freeze_factor must be at least 1; ";
  if (!(max_edge_ratio > 1.0))
    why << "max_edge_ratio must exceed 1; ";
  if (texture_window_px < 5 || texture_window_px % 2 == 0)
    why << "texture_window_px must be odd and >= 5; ";
  if (texture_refinement_window_px != 0 && (texture_refinement_window_px < 5 || texture_refinement_window_px % 2 == 0))
    why << "texture_refinement_window_px must be 0 (off) or odd and >= 5; ";
  if (texture_pyramid_levels < 0 || texture_pyramid_levels > 6)
    why << "texture_pyramid_levels must be in [0, 6]; ";
  if (!(texture_error_inflation >= 1.0))
    why << "texture_error_inflation must be at least 1; ";
  if (!(texture_depth_sigma_m >= 0.0) || !(texture_extrapolated_depth_sigma_m > 0.0))
    why << "texture depth sigmas must not be negative (the extrapolated one positive); ";
  if (texture_max_features < 0 || texture_min_features < 0)
    why << "texture feature counts must not be negative; ";
  if (texture_max_level < 0 || texture_max_level > 4)
    why << "texture_max_level must be in [0, 4]; ";
  if (!(texture_min_snr >= 0.0) || !(texture_max_sigma_px > 0.0))
    why << "texture_min_snr must not be negative and texture_max_sigma_px must be positive; ";
  if (!(filter_acceleration_noise > 0.0) || !(filter_angular_acceleration_noise > 0.0))
    why << "filter noise densities must be positive; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

}  // namespace structured_light_stabilizer
