#include "service/zmq/curve_keys.hpp"

#include <zmq.h>

#include <array>
#include <cstdint>
#include <fstream>
#include <vector>

#include "common/errors.hpp"

namespace pointillist::service {
namespace {

constexpr std::size_t kZ85KeyLength = 40;

bool isZ85Key(const std::string& text) {
  if (text.size() != kZ85KeyLength) return false;
  std::array<std::uint8_t, 32> binary{};
  return zmq_z85_decode(binary.data(), text.c_str()) != nullptr;
}

std::vector<std::string> keyLines(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) throw InputError(file.string() + ": cannot read the key file");
  std::vector<std::string> keys;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    // Z85 has '#' among its characters: only a line starting with it is a comment.
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    line = line.substr(first, line.find_last_not_of(" \t\r") - first + 1);
    if (!isZ85Key(line)) {
      throw InputError(file.string() + ":" + std::to_string(number) +
                       ": not a Z85 CURVE key (40 characters)");
    }
    keys.push_back(line);
  }
  return keys;
}

void writeText(const std::filesystem::path& file, const std::string& text, bool secret) {
  {
    std::ofstream out(file, std::ios::trunc);
    if (!out) throw Error("cannot write " + file.string());
    out << text << '\n';
  }
  if (secret) {
    std::filesystem::permissions(
        file, std::filesystem::perms::owner_read | std::filesystem::perms::owner_write);
  }
}

}  // namespace

void requireCurve() {
  if (zmq_has("curve") == 0) throw UsageError("this libzmq has no CURVE support");
}

CurveKeyPair generateCurveKeyPair() {
  requireCurve();
  std::array<char, kZ85KeyLength + 1> publicKey{}, secretKey{};
  if (zmq_curve_keypair(publicKey.data(), secretKey.data()) != 0) {
    throw Error(std::string("zmq_curve_keypair: ") + zmq_strerror(zmq_errno()));
  }
  return {publicKey.data(), secretKey.data()};
}

std::string readCurveKey(const std::filesystem::path& file) {
  const auto keys = keyLines(file);
  if (keys.size() != 1) {
    throw InputError(file.string() + ": holds " + std::to_string(keys.size()) +
                     " keys, expected one");
  }
  return keys.front();
}

std::string curvePublicKey(const std::string& secretZ85) {
  requireCurve();
  std::array<char, kZ85KeyLength + 1> publicKey{};
  if (zmq_curve_public(publicKey.data(), secretZ85.c_str()) != 0) {
    throw InputError("not a CURVE secret key");
  }
  return publicKey.data();
}

std::set<std::string> readAuthorizedKeys(const std::filesystem::path& file) {
  std::set<std::string> keys;
  for (const std::string& key : keyLines(file)) {
    std::array<std::uint8_t, 32> binary{};
    zmq_z85_decode(binary.data(), key.c_str());
    keys.emplace(reinterpret_cast<const char*>(binary.data()), binary.size());
  }
  if (keys.empty()) throw InputError(file.string() + ": no client keys: nobody could connect");
  return keys;
}

CurveKeyPair writeCurveKeyPair(const std::string& prefix) {
  const CurveKeyPair pair = generateCurveKeyPair();
  writeText(prefix + ".secret", pair.secretKey, true);
  writeText(prefix + ".public", pair.publicKey, false);
  return pair;
}

}  // namespace pointillist::service
