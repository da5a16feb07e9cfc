// Choice of gas-solid drag law by name ("bvk", "bvk2", "koch_hill", "wen_yu", "none") and one
// dispatch kernel giving beta_i for one particle (docs/theory.md §4).
#pragma once

#include <string_view>

#include "fluid/bvk2_drag.hpp"
#include "fluid/bvk_drag.hpp"
#include "fluid/koch_hill_drag.hpp"
#include "fluid/wen_yu_drag.hpp"

namespace cfddem::fluid {

enum class DragLaw { none, bvk, bvk2, koch_hill, wen_yu };

// Parses a scene's drag name; throws std::invalid_argument naming the value and the choices.
[[nodiscard]] DragLaw parse_drag_law(std::string_view name);
[[nodiscard]] std::string_view drag_law_name(DragLaw law);

// beta_i [N s/m] for one particle: F_d = beta_i (u_g - v_i). slip = |u_g - v_i|.
[[nodiscard]] inline double drag_beta(DragLaw law, double eps_g, double d, double slip,
                                      double rho_g, double mu_g) {
  switch (law) {
  case DragLaw::bvk:
    return bvk_beta(eps_g, d, slip, rho_g, mu_g);
  case DragLaw::bvk2:
    return bvk2_beta(eps_g, d, slip, rho_g, mu_g);
  case DragLaw::koch_hill:
    return koch_hill_beta(eps_g, d, slip, rho_g, mu_g);
  case DragLaw::wen_yu:
    return wen_yu_beta(eps_g, d, slip, rho_g, mu_g);
  case DragLaw::none:
    break;
  }
  return 0.0;
}

} // namespace cfddem::fluid
