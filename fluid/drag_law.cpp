#include "fluid/drag_law.hpp"

#include <stdexcept>
#include <string>

namespace cfddem::fluid {

DragLaw parse_drag_law(std::string_view name) {
  for (const DragLaw law :
       {DragLaw::none, DragLaw::bvk, DragLaw::bvk2, DragLaw::koch_hill, DragLaw::wen_yu}) {
    if (name == drag_law_name(law)) {
      return law;
    }
  }
  throw std::invalid_argument("unknown drag law \"" + std::string(name) +
                              "\" (choose bvk, bvk2, koch_hill, wen_yu or none)");
}

std::string_view drag_law_name(DragLaw law) {
  switch (law) {
  case DragLaw::bvk:
    return "bvk";
  case DragLaw::bvk2:
    return "bvk2";
  case DragLaw::koch_hill:
    return "koch_hill";
  case DragLaw::wen_yu:
    return "wen_yu";
  case DragLaw::none:
    break;
  }
  return "none";
}

} // namespace cfddem::fluid
